"""LSV2 numbers and names: error codes, logins, sub-commands, selectors, enumerations.

Names follow the protocol reference (``docs/lsv2.md``); values are what travels on the
wire. Everything here is plain data, shared by the client and the simulator.
"""

from __future__ import annotations

import enum

DEFAULT_PORT = 19000
DEFAULT_BUFFER_SIZE = 256
"""Every session starts with 256-byte telegrams (header included) until ``C_CC`` changes it."""


class ErrorCode(enum.IntEnum):
    """Error codes carried by ``T_ER`` (20-99) and ``T_BD`` (100-200)."""

    T_ER_BAD_FORMAT = 20
    T_ER_UNEXPECTED_TELE = 21
    T_ER_UNKNOWN_TELE = 22
    T_ER_NO_PRIV = 23
    T_ER_WRONG_PARA = 24
    T_ER_BREAK = 25
    T_ER_BAD_KEY = 30
    T_ER_BAD_FNAME = 31
    T_ER_NO_FILE = 32
    T_ER_OPEN_FILE = 33
    T_ER_FILE_EXISTS = 34
    T_ER_BAD_FILE = 35
    T_ER_NO_DELETE = 36
    T_ER_NO_NEW_FILE = 37
    T_ER_NO_CHANGE_ATT = 38
    T_ER_BAD_EMULATEKEY = 39
    T_ER_NO_MP = 40
    T_ER_NO_WIN = 41
    T_ER_WIN_NOT_AKTIV = 42
    T_ER_ANZ = 43
    T_ER_FONT_NOT_DEFINED = 44
    T_ER_FILE_ACCESS = 45
    T_ER_WRONG_DNC_STATUS = 46
    T_ER_CHANGE_PATH = 47
    T_ER_NO_RENAME = 48
    T_ER_NO_LOGIN = 49
    T_ER_BAD_PARAMETER = 50
    T_ER_BAD_NUMBER_FORMAT = 51
    T_ER_BAD_MEMADR = 52
    T_ER_NO_FREE_SPACE = 53
    T_ER_DEL_DIR = 54
    T_ER_NO_DIR = 55
    T_ER_OPERATING_MODE = 56
    T_ER_NO_NEXT_ERROR = 57
    T_ER_ACCESS_TIMEOUT = 58
    T_ER_NO_WRITE_ACCESS = 59
    T_ER_STIB = 60
    T_ER_REF_NECESSARY = 61
    T_ER_PLC_BUF_FULL = 62
    T_ER_NOT_FOUND = 63
    T_ER_WRONG_FILE = 64
    T_ER_NO_MATCH = 65
    T_ER_TOO_MANY_TPTS = 66
    T_ER_NOT_ACTIVATED = 67
    T_ER_DSP_CHANNEL = 70
    T_ER_DSP_PARA = 71
    T_ER_OUT_OF_RANGE = 72
    T_ER_INVALID_AXIS = 73
    T_ER_STREAMING_ACTIVE = 74
    T_ER_NO_STREAMING_ACTIVE = 75
    T_ER_TO_MANY_OPEN_TCP = 80
    T_ER_NO_FREE_HANDLE = 81
    T_ER_PLCMEMREMA_CLEAR = 82
    T_ER_OSZI_CHSEL = 83
    T_ER_TOO_MANY_SIGNALS = 85
    T_BD_NO_NEW_FILE = 100
    T_BD_NO_FREE_SPACE = 101
    T_BD_FILE_NOT_ALLOWED = 102
    T_BD_BAD_FORMAT = 103
    T_BD_BAD_BLOCK = 104
    T_BD_END_PGM = 105
    T_BD_ANZ = 106
    T_BD_WIN_NOT_DEFINED = 107
    T_BD_WIN_CHANGED = 108
    T_BD_DNC_WAIT = 110
    T_BD_CANCELLED = 111
    T_BD_OSZI_OVERRUN = 112
    T_BD_FD = 200
    T_USER_ERROR = 255


ERROR_TEXT: dict[int, str] = {
    20: "telegram malformed",
    21: "telegram not allowed now",
    22: "unknown telegram",
    23: "missing login privilege",
    24: "wrong or unsupported parameter",
    25: "cancelled by the operator",
    30: "bad key number or password",
    31: "bad file or path name",
    32: "file not found",
    33: "file could not be opened",
    34: "file already exists",
    35: "file type not allowed",
    36: "file could not be deleted",
    37: "file could not be created",
    38: "attributes cannot be changed",
    39: "key emulation refused",
    40: "machine parameter wrong or not supported",
    41: "wrong window or screen number",
    42: "window not active",
    43: "display task failed",
    44: "font not defined",
    45: "file access error",
    46: "not allowed in the current DNC state",
    47: "directory change failed",
    48: "rename failed",
    49: "login not possible",
    50: "bad parameter in telegram",
    51: "bad number format",
    52: "bad memory address",
    53: "not enough free space",
    54: "directory could not be deleted",
    55: "directory does not exist",
    56: "wrong operating mode",
    57: "no further NC error message",
    58: "timeout while waiting for data",
    59: "no write access",
    60: "DNC mode cannot start while the machine is active",
    61: "DNC mode cannot start: axes not referenced",
    62: "PLC buffer full",
    63: "requested information not found",
    64: "wrong file type or format",
    65: "PLC binary does not match the control",
    66: "too many trace points",
    67: "file could not be activated",
    70: "DSP channel not available",
    71: "DSP data could not be read",
    72: "parameter out of range",
    73: "invalid axis",
    74: "axis streaming already active",
    75: "no axis streaming active",
    80: "too many TCP connections",
    81: "no free LSV2 handle",
    82: "retentive PLC memory was cleared",
    83: "scope channel selection invalid",
    85: "too many scope signals selected",
    100: "block transfer: file could not be created",
    101: "block transfer: not enough free memory",
    102: "block transfer: file not allowed",
    103: "block transfer: format error (no line end or T_FD sent)",
    104: "block transfer: error in an NC program block",
    105: "block transfer: end of program already reached",
    106: "block transfer: display task failed",
    107: "block transfer: window not defined",
    108: "block transfer: window has changed",
    110: "block transfer: DNC buffer full",
    111: "block transfer: cancelled by the operator",
    112: "block transfer: scope buffer overrun",
    200: "block transfer finished",
    255: "user error with text message",
}


def error_text(code: int | None) -> str:
    """Readable meaning of an LSV2 error code (``"unknown error 77"`` for unlisted codes)."""
    if code is None:
        return "error without code"
    return ERROR_TEXT.get(code, f"unknown error {code}")


class Login(enum.StrEnum):
    """Login names as sent in ``A_LG`` (see docs/lsv2.md#logins)."""

    INSPECT = "INSPECT"
    DIAGNOSTICS = "DIAGNOSTICS"
    FILE = "FILE"
    MONITOR = "MONITOR"
    DNC = "DNC"
    PLCDEBUG = "PLCDEBUG"
    DATA = "DATA"
    OSZI = "OSZI"
    DSP = "DSP"
    STREAMAXES = "STREAMAXES"
    FILEPLC = "FILEPLC"
    FILESYS = "FILESYS"
    FILELOG = "FILELOG"


PLC_DEFAULT_PASSWORD = "807667"
"""The publicly known default PLC code number (PLCDEBUG / FILEPLC)."""


class CcCommand(enum.IntEnum):
    """Sub-commands of ``C_CC``."""

    RESET_TNC = 1
    STOP_TIMEUPDATE = 2
    SET_BUF1024 = 3
    SET_BUF512 = 4
    SET_BUF2048 = 5
    SET_BUF3072 = 6
    SET_BUF4096 = 7
    RESET_DNC = 8
    RESET_LSV2 = 9
    UPDATE_TNCOPT = 10
    PUSH_PRESET_INTO_LOG = 11
    SCREENDUMP = 12
    ACTIVATE_PLCPGM = 13
    OBSERVE_ADD_FILE = 15
    OBSERVE_REMOVE_FILE = 16
    OBSERVE_REMOVE_ALL = 17
    ACTIVATE_MFSK = 18
    SECURE_FILE_SEND = 19
    DELETE_TABLE_ENTRY = 20
    GENERATE_OP_LOG = 27


BUFFER_COMMANDS: dict[int, CcCommand] = {
    512: CcCommand.SET_BUF512,
    1024: CcCommand.SET_BUF1024,
    2048: CcCommand.SET_BUF2048,
    3072: CcCommand.SET_BUF3072,
    4096: CcCommand.SET_BUF4096,
}
"""Buffer size -> ``C_CC`` sub-command (note the odd order: 1024 is 3, 512 is 4)."""

BUFFER_SIZES: dict[int, int] = {int(cmd): size for size, cmd in BUFFER_COMMANDS.items()}
"""``C_CC`` sub-command -> buffer size it selects."""


class VersionSelector(enum.IntEnum):
    """``R_VR`` selectors for a single version string."""

    CONTROL = 1
    NC_SOFTWARE = 2
    PLC = 3
    OPTIONS = 4
    ID = 5
    RELEASE_TYPE = 6
    SPLC = 7


class SystemInfoSelector(enum.IntEnum):
    """``R_CI`` selectors."""

    TURBO_MODE = 1
    DNC_ALLOWED = 2
    AXES_SAMPLING_RATE = 3


class SystemInfoType(enum.IntEnum):
    """Value type in an ``S_CI`` answer."""

    BOOLEAN = 1
    NUMBER = 2


class RunInfo(enum.IntEnum):
    """``R_RI`` selectors (run-time information)."""

    AXES_CONFIG = 20
    AXES_NAMES = 21
    AXES_POSITION = 22
    EXEC_STATE = 23
    SELECTED_PGM = 24
    OVERRIDE = 25
    PGM_STATE = 26
    FIRST_ERROR = 27
    NEXT_ERROR = 28
    NC_UPTIME = 30
    MACHINE_UPTIME = 31
    MACHINE_RUNTIME = 32
    SPINDLE1_RUNTIME = 33
    SPINDLE2_RUNTIME = 34
    CURRENT_TOOL = 51


class ExecutionMode(enum.IntEnum):
    """Execution mode (``R_RI`` 23)."""

    MANUAL = 0
    MDI = 1
    PASS_REFERENCES = 2
    SINGLE_STEP = 3
    AUTOMATIC = 4
    UNDEFINED = 5


class ProgramState(enum.IntEnum):
    """Program state (``R_RI`` 26)."""

    STARTED = 0
    STOPPED = 1
    FINISHED = 2
    CANCELLED = 3
    INTERRUPTED = 4
    ERROR = 5
    ERROR_CLEARED = 6
    IDLE = 7
    UNDEFINED = 8


class MemoryType(enum.IntEnum):
    """PLC memory areas (values as pyLSV2 numbers them)."""

    MARKER = 1
    INPUT = 2
    OUTPUT = 3
    COUNTER = 4
    TIMER = 5
    BYTE = 6
    WORD = 7
    DWORD = 8
    STRING = 9
    INPUT_WORD = 10
    OUTPUT_WORD = 11
    OUTPUT_DWORD = 12
    INPUT_DWORD = 13


class ScopeOperand(enum.IntEnum):
    """PLC operand types in an ``R_OP`` signal selector (scope channels of type 2/10)."""

    M = 0
    T = 1
    C = 2
    I = 3  # noqa: E741 - the operand is called I
    O = 4  # noqa: E741 - the operand is called O
    B = 5
    W = 6
    D = 7
    IB = 8
    IW = 9
    ID = 10
    OB = 11
    OW = 12
    OD = 13


class ScopeChannelType(enum.IntEnum):
    """Channel types in an ``S_OC`` description."""

    NO_PARAMETER = 0
    PER_AXIS = 1
    PLC_OPERAND = 2
    TYPE3 = 3
    PER_AXIS_2 = 4
    PLC_OPERAND_2 = 10


class DataType(enum.IntEnum):
    """Value types of an ``S_DP`` answer."""

    INT16 = 2
    INT32 = 3
    FLOAT64 = 5
    STRING = 8
    BOOL = 11
    INT8 = 16
    UINT8 = 17


class TransferMode(enum.IntEnum):
    """Mode byte after the path in ``C_FL`` / ``R_FL``."""

    ASCII = 0
    BINARY = 1
    MERGE = 2


class DirMode(enum.IntEnum):
    """``R_DR`` modes."""

    SINGLE = 0
    MULTI = 1
    DRIVES = 2


class NewAttr(enum.IntFlag):
    """File attribute bits, scheme of TNC 3xx/6xx/7, lathes and MillPlus."""

    SHOWN = 0x01
    CHANGEABLE = 0x02
    HIGHLIGHTED = 0x04
    HIDDEN = 0x08
    DRIVE = 0x10
    DIRECTORY = 0x20
    WRITE_PROTECTED = 0x40
    SELECTED = 0x80


class OldAttr(enum.IntFlag):
    """File attribute bits, scheme of the iTNC 530 (LSV2 v1 document)."""

    SHOWN = 0x01
    CHANGEABLE = 0x02
    HIGHLIGHTED = 0x04
    HIDDEN = 0x08
    WRITE_PROTECTED = 0x20
    DIRECTORY = 0x40


class AttributeScheme(enum.Enum):
    """Which attribute-bit table a control uses."""

    OLD = "old"
    NEW = "new"

    @property
    def directory_bit(self) -> int:
        """The bit marking a directory in this scheme."""
        return 0x40 if self is AttributeScheme.OLD else 0x20

    @property
    def write_protected_bit(self) -> int:
        """The bit marking a write-protected entry in this scheme."""
        return 0x20 if self is AttributeScheme.OLD else 0x40


class Family(enum.Enum):
    """Control families that behave differently on LSV2."""

    ITNC530 = "iTNC 530"
    TNC_NEW = "TNC 128/320/620/640"
    TNC7 = "TNC7"
    LATHE_NEW = "CNC PILOT / MANUALplus"
    MILLPLUS = "MillPlus IT"
    TNC4XX = "TNC 426/430"
    UNKNOWN = "unknown"

    @property
    def attribute_scheme(self) -> AttributeScheme:
        """Old scheme on iTNC 530 and TNC 4xx, new elsewhere."""
        if self in (Family.ITNC530, Family.TNC4XX):
            return AttributeScheme.OLD
        return AttributeScheme.NEW

    @property
    def is_itnc(self) -> bool:
        """True for the iTNC 530 (tool/error selectors, data paths, scope)."""
        return self is Family.ITNC530

    @property
    def uses_old_keys(self) -> bool:
        """TNC 4xx controls expect the old key-code table."""
        return self is Family.TNC4XX


_FAMILY_PREFIXES: tuple[tuple[str, Family], ...] = (
    ("ITNC530", Family.ITNC530),
    ("TNC640", Family.TNC_NEW),
    ("TNC620", Family.TNC_NEW),
    ("TNC320", Family.TNC_NEW),
    ("TNC128", Family.TNC_NEW),
    ("TNC7", Family.TNC7),
    ("MANUALPLUS", Family.LATHE_NEW),
    ("CNCPILOT640", Family.LATHE_NEW),
    ("MILLPLUS", Family.MILLPLUS),
    ("TNC426", Family.TNC4XX),
    ("TNC430", Family.TNC4XX),
    ("TNC425", Family.TNC4XX),
    ("TNC410", Family.TNC4XX),
)


def detect_family(model: str) -> Family:
    """Classify a control by its model string (``R_VR`` selector 1 / first ``S_VR`` part).

    Blanks are removed and case ignored, so ``"TNC 426/430M"`` is a TNC 4xx and
    ``"iTNC530 Programmierplatz"`` an iTNC 530.
    """
    key = "".join(model.split()).upper()
    for prefix, family in _FAMILY_PREFIXES:
        if key.startswith(prefix):
            return family
    return Family.UNKNOWN


class KeyCode(enum.IntEnum):
    """Key codes for ``C_EK``, current style (TNC 3xx/6xx, newer iTNC software)."""

    BACKSPACE = 0x0008
    LINE_FEED = 0x000A
    RETURN = 0x000D
    SPACE = 0x0020
    COLON = 0x003A
    SOFTKEY_NEXT_ROW = 0x019D
    SOFTKEY_PREV_ROW = 0x019E
    ARROW_UP = 0x01A0
    ARROW_DOWN = 0x01A1
    ARROW_LEFT = 0x01A2
    ARROW_RIGHT = 0x01A3
    ENT = 0x01A8
    NO_ENT = 0x01A9
    DEL = 0x01AB
    END = 0x01AC
    GOTO = 0x01AD
    CE = 0x01AE
    AXIS_X = 0x01B0
    AXIS_Y = 0x01B1
    AXIS_Z = 0x01B2
    AXIS_4 = 0x01B3
    AXIS_5 = 0x01B4
    POLAR = 0x01B8
    INCREMENTAL = 0x01B9
    Q = 0x01BA
    ACTUAL_POSITION = 0x01BB
    SIGN = 0x01BC
    DECIMAL_POINT = 0x01BD
    MODE_MANUAL = 0x01C0
    MODE_MDI = 0x01C1
    MODE_SINGLE_STEP = 0x01C2
    MODE_AUTOMATIC = 0x01C3
    MODE_PGM_EDIT = 0x01C4
    MODE_HANDWHEEL = 0x01C5
    MODE_TEST_RUN = 0x01C6
    MOD = 0x01C7
    PGM_MGT = 0x01CB
    PGM_CALL = 0x01D0
    TOOL_DEF = 0x01D1
    TOOL_CALL = 0x01D2
    CYCL_DEF = 0x01D3
    CYCL_CALL = 0x01D4
    LBL_SET = 0x01D5
    LBL_CALL = 0x01D6
    PATH_L = 0x01D7
    PATH_C = 0x01D8
    PATH_CR = 0x01D9
    PATH_CT = 0x01DA
    PATH_CC = 0x01DB
    PATH_RND = 0x01DC
    PATH_CHF = 0x01DD
    PATH_FK = 0x01DE
    TOUCH_PROBE = 0x01DF
    STOP = 0x01E0
    APPR_DEP = 0x01E1
    HELP = 0x01ED
    INFO = 0x01EE
    CALC = 0x01EF

    @staticmethod
    def digit(n: int) -> int:
        """Code of digit key ``n`` (0-9)."""
        return 0x30 + n

    @staticmethod
    def letter(ch: str) -> int:
        """Code of letter key ``ch`` (A-Z / a-z)."""
        return ord(ch)

    @staticmethod
    def left_softkey(n: int) -> int:
        """Left soft key ``n`` (0-9)."""
        return 0x0150 + n

    @staticmethod
    def right_softkey(n: int) -> int:
        """Right soft key ``n`` (0-8)."""
        return 0x0160 + n

    @staticmethod
    def bottom_softkey(n: int) -> int:
        """Bottom soft key ``n`` (0-9)."""
        return 0x0180 + n


class OldKeyCode(enum.IntEnum):
    """Key codes for ``C_EK``, old style (TNC 4xx and old iTNC software)."""

    CHANGE_SCREEN = 0x0052
    SPLIT_SCREEN = 0x0152
    SOFTKEY_PREV_ROW = 0x0851
    SOFTKEY_NEXT_ROW = 0x0A51
    ENT = 0x0065
    NO_ENT = 0x005F
    DEL = 0x0063
    CE = 0x0069
    END = 0x0077
    SIGN = 0x007C
    DECIMAL_POINT = 0x0073
    ACTUAL_POSITION = 0x0064
    INCREMENTAL = 0x0044
    POLAR = 0x0043
    NUM_0 = 0x006E
    NUM_1 = 0x0070
    NUM_2 = 0x0074
    NUM_3 = 0x007D
    NUM_4 = 0x0071
    NUM_5 = 0x0075
    NUM_6 = 0x007E
    NUM_7 = 0x0072
    NUM_8 = 0x0076
    NUM_9 = 0x007F
    MODE_MANUAL = 0x0048
    MODE_HANDWHEEL = 0x0040
    MODE_SINGLE_STEP = 0x004A
    MODE_MDI = 0x0049
    MODE_TEST_RUN = 0x0041
    MODE_AUTOMATIC = 0x004B
    MODE_PGM_EDIT = 0x004C
    MOD = 0x0042
    PGM_MGT = 0x0061
    AXIS_X = 0x006D
    AXIS_Y = 0x006C
    AXIS_Z = 0x006B
    AXIS_4 = 0x006A
    AXIS_5 = 0x004F
    PATH_L = 0x003C
    PATH_C = 0x003F
    PATH_CR = 0x0047
    PATH_CT = 0x004D
    PATH_CC = 0x003E
    PATH_RND = 0x003D
    PATH_CHF = 0x003A
    APPR_DEP = 0x0078
    RADIUS_RIGHT = 0x0057
    RADIUS_LEFT = 0x0056
    TOOL_DEF = 0x0054
    TOOL_CALL = 0x0055
    CYCL_DEF = 0x005B
    CYCL_CALL = 0x005C
    LBL_SET = 0x005D
    LBL_CALL = 0x005E
    PGM_CALL = 0x0045
    STOP = 0x0060
    TOUCH_PROBE = 0x004E
    BLK_FORM = 0x00FF
    CL_PGM = 0x0062
    PGM_NR = 0x003B
    ARROW_LEFT = 0x0059
    ARROW_DOWN = 0x0067
    ARROW_UP = 0x0058
    ARROW_RIGHT = 0x005A
    GOTO = 0x0066

    @staticmethod
    def character(ch: str) -> int:
        """Old-style code of ASCII character ``ch``: high byte = character, low byte 0x50."""
        return (ord(ch) << 8) | 0x50

    @staticmethod
    def bottom_softkey(n: int) -> int:
        """Old-style bottom soft key ``n`` (0-7)."""
        return (n << 8) | 0x51


BINARY_EXTENSIONS: frozenset[str] = frozenset(
    [
        ".ads",
        ".bak",
        ".bck",
        ".bin",
        ".bmp",
        ".bmx",
        ".chm",
        ".cyc",
        ".cy%",
        ".dmp",
        ".dll",
        ".eak",
        ".elf",
        ".enc",
        ".exe",
        ".gds",
        ".gif",
        ".hbi",
        ".he",
        ".ioc",
        ".iocp",
        ".jpg",
        ".jpeg",
        ".map",
        ".mds",
        ".mo",
        ".omf",
        ".pdf",
        ".png",
        ".pyc",
        ".s",
        ".sds",
        ".sk",
        ".str",
        ".xml",
        ".xls",
        ".xrs",
        ".zip",
    ]
)
"""File extensions always transferred in binary mode (as pyLSV2 does)."""

DRIVES = ("TNC:", "PLC:", "SYS:", "LOG:")
DRIVE_LOGINS: dict[str, Login] = {
    "TNC:": Login.FILE,
    "PLC:": Login.FILEPLC,
    "SYS:": Login.FILESYS,
    "LOG:": Login.FILELOG,
}
"""The login that opens each drive."""
