"""Control-family profiles of the virtual TNC.

A profile is everything that makes one Heidenhain family answer differently from another:
version strings, the system-parameter block (PLC area layout, maximum block length), the
drive and table layout, which logins, ``R_RI`` selectors, buffer sizes and optional
telegrams exist, and the attribute bit scheme of file entries.  Values marked as captured
in the protocol reference (TNC 320 v18, iTNC 530, TNC 426) are used verbatim.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from enum import Enum

from opendnc.errors import InputError
from opendnc.lsv2.constants import BUFFER_SIZES, DRIVE_LOGINS
from opendnc.lsv2.payloads import SystemParameters


class KeyStyle(Enum):
    """Which key-code table ``C_EK`` understands (docs/lsv2.md#key-codes)."""

    NEW = "new"
    OLD = "old"
    NONE = "none"


@dataclass(frozen=True, slots=True)
class PlcLayout:
    """Start addresses and sizes of the PLC areas inside one flat byte image
    (docs/lsv2.md#system-parameters)."""

    markers_start: int
    markers: int
    inputs_start: int
    inputs: int
    outputs_start: int
    outputs: int
    counters_start: int
    counters: int
    timers_start: int
    timers: int
    words_start: int
    words: int
    strings_start: int
    strings: int
    string_length: int
    input_words_start: int
    input_words: int
    output_words_start: int
    output_words: int

    @property
    def image_size(self) -> int:
        """Bytes needed to back every area."""
        ends = [
            self.markers_start + self.markers,
            self.inputs_start + self.inputs,
            self.outputs_start + self.outputs,
            self.counters_start + self.counters,
            self.timers_start + self.timers,
            self.words_start + self.words,
            self.strings_start + self.strings * self.string_length,
            self.input_words_start + self.input_words,
            self.output_words_start + self.output_words,
        ]
        return max(ends)


def _tiled_layout(words: int, markers: int, io: int, counters: int, timers: int) -> PlcLayout:
    """Lay the areas out back to back the way the captured TNC 320 does (words first at 64)."""
    words_start = 64
    iw_start = words_start + words
    ow_start = iw_start + io
    m_start = ow_start + io
    i_start = m_start + markers
    o_start = i_start + io
    c_start = o_start + io
    t_start = c_start + counters
    s_start = t_start + timers
    return PlcLayout(
        markers_start=m_start,
        markers=markers,
        inputs_start=i_start,
        inputs=io,
        outputs_start=o_start,
        outputs=io,
        counters_start=c_start,
        counters=counters,
        timers_start=t_start,
        timers=timers,
        words_start=words_start,
        words=words,
        strings_start=s_start,
        strings=400,
        string_length=240,
        input_words_start=iw_start,
        input_words=io,
        output_words_start=ow_start,
        output_words=io,
    )


# Captured TNC 320 v18 layout (golden vector of docs/lsv2.md#system-parameters): the tiling
# reproduces it exactly.
TNC_LAYOUT = _tiled_layout(words=120000, markers=40000, io=1000, counters=144, timers=1000)
# iTNC 530 / TNC 426: smaller PLC (values plausible, not captured); word area >= 1700 bytes.
ITNC_LAYOUT = _tiled_layout(words=20000, markers=10000, io=512, counters=96, timers=512)
OLD_LAYOUT = _tiled_layout(words=8192, markers=4096, io=256, counters=48, timers=256)


@dataclass(frozen=True, slots=True)
class PathLayout:
    """Well-known files of a family (docs/tnc-profiles.md#paths-and-drives)."""

    program_dir: str
    mdi_program: str
    tool_table: str
    pocket_table: str
    program_ext: tuple[str, ...]
    #: A second program folder whose programs sit in sub-folders (the iTNC 530 programming
    #: station ships ``TNC:\\nc_prog`` next to the programs in ``TNC:\\``); None: no such folder.
    project_dir: str | None = None


NEW_PATHS = PathLayout(
    program_dir="TNC:\\nc_prog",
    mdi_program="TNC:\\nc_prog\\$mdi.h",
    tool_table="TNC:\\table\\tool.t",
    pocket_table="TNC:\\table\\tool_p.tch",
    program_ext=(".h", ".i"),
)
ITNC_PATHS = PathLayout(
    program_dir="TNC:\\",
    mdi_program="TNC:\\$MDI.H",
    tool_table="TNC:\\TOOL.T",
    pocket_table="TNC:\\TOOL_P.TCH",
    program_ext=(".H", ".I"),
)
ITNC530_PATHS = PathLayout(
    program_dir=ITNC_PATHS.program_dir,
    mdi_program=ITNC_PATHS.mdi_program,
    tool_table=ITNC_PATHS.tool_table,
    pocket_table=ITNC_PATHS.pocket_table,
    program_ext=ITNC_PATHS.program_ext,
    project_dir="TNC:\\nc_prog",
)
LATHE_PATHS = PathLayout(
    program_dir="TNC:\\nc_prog\\ncps",
    mdi_program="TNC:\\nc_prog\\ncps\\PGM01.nc",
    tool_table="TNC:\\table\\toolturn.htt",
    pocket_table="TNC:\\table\\ToolAllo.tch",
    program_ext=(".nc",),
)

BASE_LOGINS = frozenset({"INSPECT", "DIAGNOSTICS", "FILE", "MONITOR", "DNC", "PLCDEBUG", "DSP"})


@dataclass(frozen=True, slots=True)
class Profile:
    """One control family as the simulator presents it."""

    key: str
    title: str
    model: str
    nc_software: str
    plc_software: str
    splc_software: str | None  # None: the empty R_VR answers 4 parts and selector 7 is refused
    option_bits: str
    control_id: str
    release_type: str | None  # None: R_VR selector 6 refused (iTNC)
    sys_par_length: int  # 120 or 124 (docs/lsv2.md#system-parameters)
    max_block_length: int
    lsv2_flags: int
    lsv2_flags_ex: int
    plc: PlcLayout
    old_attributes: bool  # iTNC scheme: 0x40 directory, 0x20 write-protected
    paths: PathLayout
    ri_selectors: frozenset[int]
    logins: frozenset[str]
    data_paths: bool
    scope: bool
    keys: KeyStyle
    delete_cwd_allowed: bool
    date_time: bool
    numeric_machine_parameters: bool
    lathe: bool = False
    drives: tuple[str, ...] = ("TNC:", "PLC:", "SYS:", "LOG:")
    plc_password: str = "807667"
    password_key: int = 0x60389A6E
    max_buffer: int = 4096
    dir_separator: str = "\\"  # separator in S_DI paths; the iTNC answers with "/" (wire)
    system_commands: frozenset[int] = field(
        default_factory=lambda: frozenset({2, 3, 4, 5, 6, 7, 8, 11, 12, 17, 19, 27})
    )
    #: Logins that open a drive besides the drive's own file login, as (drive, login) pairs.
    #: A TNC 640 in the field serves ``LOG:`` to a client logged in as FILEPLC only.
    shared_drive_logins: frozenset[tuple[str, str]] = frozenset()

    def drive_logins(self, drive: str) -> frozenset[str]:
        """Every login that opens ``drive`` on this family (empty for an unknown drive)."""
        own = DRIVE_LOGINS.get(drive)
        if own is None:
            return frozenset()
        return frozenset({own.value}) | {
            login for d, login in self.shared_drive_logins if d == drive
        }

    def version_parts(self) -> list[str]:
        """Strings of the answer to an empty ``R_VR`` (4 or 5 parts, docs/lsv2.md#versions)."""
        parts = [self.model, self.nc_software, self.plc_software]
        if self.splc_software is not None:
            parts.append(self.splc_software)
        parts.append(self.option_bits)
        return parts

    def version_selector(self, selector: int) -> str | None:
        """Answer of ``R_VR`` with one selector byte, or None when refused."""
        table: dict[int, str | None] = {
            1: self.model,
            2: self.nc_software,
            3: self.plc_software,
            4: self.option_bits,
            5: self.control_id,
            6: self.release_type,
            7: self.splc_software,
        }
        return table.get(selector)

    def buffer_sizes(self) -> dict[int, int]:
        """C_CC buffer sub-commands this family accepts."""
        return {c: s for c, s in BUFFER_SIZES.items() if s <= self.max_buffer}

    def parameters(self) -> SystemParameters:
        """The ``S_PR`` answer as the codec's typed value (layout of docs/lsv2.md#system-parameters
        lives in the codec)."""
        return SystemParameters(
            **asdict(self.plc),
            lsv2_version=1,
            lsv2_flags=self.lsv2_flags,
            max_block_length=self.max_block_length,
            lsv2_flags_ex=self.lsv2_flags_ex,
            max_trace_lines=128,
            scope_channels=32,
            password_key=self.password_key,
            extra=0 if self.sys_par_length == 124 else None,
        )

    def system_parameters(self) -> bytes:
        """The ``S_PR`` payload (120 or 124 bytes)."""
        return self.parameters().to_bytes()


_NEW_RI = frozenset({20, 21, 22, 23, 24, 25, 26, 30, 31, 32, 33, 34})
_ITNC_RI = _NEW_RI | {27, 28, 51}

PROFILES: dict[str, Profile] = {
    "tnc640": Profile(
        key="tnc640",
        title="TNC 640 programming station",
        model="TNC640",
        nc_software="340595 11 SP4",
        plc_software="17-M008-V01SP11",
        splc_software="No version given",
        option_bits="0000000100000101",
        control_id="3405951100",
        release_type="Release",
        sys_par_length=120,
        max_block_length=4096,
        lsv2_flags=0x9F,
        lsv2_flags_ex=0x001F16FD,
        plc=TNC_LAYOUT,
        old_attributes=False,
        paths=NEW_PATHS,
        ri_selectors=_NEW_RI,
        logins=BASE_LOGINS | {"FILEPLC", "FILESYS", "FILELOG", "STREAMAXES"},
        data_paths=False,
        scope=False,
        keys=KeyStyle.NEW,
        delete_cwd_allowed=False,
        date_time=True,
        numeric_machine_parameters=False,
        # Field report: a client logged in as FILEPLC only reads LOG:\oem\python\…
        # (docs/tnc-profiles.md#drives-and-logins).
        shared_drive_logins=frozenset({("LOG:", "FILEPLC")}),
    ),
    "tnc620": Profile(
        key="tnc620",
        title="TNC 620 programming station",
        model="TNC620",
        nc_software="817605 04 SP1",
        plc_software="Basic V04-01",
        splc_software="No version given",
        option_bits="0000000100000100",
        control_id="8176050400",
        release_type="Release",
        sys_par_length=120,
        max_block_length=4096,
        lsv2_flags=0x9F,
        lsv2_flags_ex=0x001F16FD,
        plc=TNC_LAYOUT,
        old_attributes=False,
        paths=NEW_PATHS,
        ri_selectors=_NEW_RI,
        logins=BASE_LOGINS | {"FILEPLC", "FILESYS", "FILELOG"},
        data_paths=False,
        scope=False,
        keys=KeyStyle.NEW,
        delete_cwd_allowed=False,
        date_time=True,
        numeric_machine_parameters=False,
    ),
    "tnc320": Profile(
        key="tnc320",
        title="TNC 320 programming station (v18, captured)",
        model="TNC320",
        nc_software="771855 18 SP1",
        plc_software="Basic V18-00",
        splc_software="No version given",
        option_bits="0000000100000100",
        control_id="7718551800",
        release_type="Release",
        sys_par_length=120,
        max_block_length=4088,
        lsv2_flags=0x9F,
        lsv2_flags_ex=0x001F16FD,
        plc=TNC_LAYOUT,
        old_attributes=False,
        paths=NEW_PATHS,
        ri_selectors=_NEW_RI,
        logins=BASE_LOGINS | {"FILEPLC", "FILESYS", "FILELOG"},
        data_paths=False,
        scope=False,
        keys=KeyStyle.NEW,
        delete_cwd_allowed=False,
        date_time=True,
        numeric_machine_parameters=False,
    ),
    "tnc7": Profile(
        key="tnc7",
        title="TNC7 programming station",
        model="TNC7",
        nc_software="817625 17 SP1",
        plc_software="Basic V17-01",
        splc_software="No version given",
        option_bits="0000000100000111",
        control_id="8176251700",
        release_type="Release",
        sys_par_length=120,
        max_block_length=4096,
        lsv2_flags=0x9F,
        lsv2_flags_ex=0x001F16FD,
        plc=TNC_LAYOUT,
        old_attributes=False,
        paths=NEW_PATHS,
        ri_selectors=_NEW_RI,
        logins=BASE_LOGINS | {"FILEPLC", "FILESYS", "FILELOG"},
        data_paths=False,
        scope=False,
        # The TNC7 reference notes key emulation "may not" exist: refused with 39.
        keys=KeyStyle.NONE,
        delete_cwd_allowed=False,
        date_time=True,
        numeric_machine_parameters=False,
    ),
    "itnc530": Profile(
        key="itnc530",
        title="iTNC 530 programming station",
        model="iTNC530 Programmierplatz",
        nc_software="340494 08 SP2",
        plc_software="800A_AA.PLC",
        splc_software=None,
        option_bits="%0000111100000000",
        control_id="3404940800",
        release_type=None,
        sys_par_length=124,
        max_block_length=4096,
        lsv2_flags=0x01,
        lsv2_flags_ex=0x0000000F,
        plc=ITNC_LAYOUT,
        old_attributes=True,
        paths=ITNC530_PATHS,
        ri_selectors=_ITNC_RI,
        logins=BASE_LOGINS | {"FILEPLC", "FILESYS", "DATA", "OSZI"},
        data_paths=True,
        scope=True,
        keys=KeyStyle.NEW,
        delete_cwd_allowed=True,
        # 340494 = variant 4, a Windows programming station: no date/time service
        # (docs/lsv2.md#date-and-time).
        date_time=False,
        numeric_machine_parameters=True,
        drives=("TNC:", "PLC:", "SYS:"),
        plc_password="807667",
        dir_separator="/",
        system_commands=frozenset({2, 3, 4, 5, 6, 7, 8, 12, 17, 19, 27}),
    ),
    "tnc426": Profile(
        key="tnc426",
        title="TNC 426/430 M",
        model="TNC 426/430M",
        # Captured with a trailing blank (pyLSV2 cannot parse its service pack).
        nc_software="280476 24 ",
        plc_software="GR495.07SA",
        splc_software=None,
        # Captured empty; pyLSV2 strips trailing NULs and then sees 3 parts, so an empty last
        # part would make every pyLSV2 connect fail.  One "0" keeps the 4-part shape.
        option_bits="0",
        control_id="2804762400",
        release_type=None,
        sys_par_length=120,
        max_block_length=1024,
        lsv2_flags=0x01,
        lsv2_flags_ex=0,
        plc=OLD_LAYOUT,
        old_attributes=True,
        paths=ITNC_PATHS,
        ri_selectors=frozenset({23, 24, 25, 26}),
        # FILEPLC (with the PLC password) opens PLC: on every family, this one included
        # (docs/tnc-profiles.md#drives-and-logins); FILESYS and FILELOG have no drive here.
        logins=frozenset(
            {"INSPECT", "DIAGNOSTICS", "FILE", "MONITOR", "DNC", "PLCDEBUG", "FILEPLC"}
        ),
        data_paths=False,
        scope=False,
        keys=KeyStyle.OLD,
        delete_cwd_allowed=True,
        date_time=False,
        numeric_machine_parameters=True,
        drives=("TNC:", "PLC:"),
        max_buffer=1024,
        system_commands=frozenset({3, 4, 12, 19}),
    ),
    "cncpilot640": Profile(
        key="cncpilot640",
        title="CNC PILOT 640 programming station",
        model="CNCPILOT640",
        # 7-digit software number as captured (pyLSV2's version parser cannot read it).
        nc_software="1230521 03 SP1",
        plc_software="Basic V03-00",
        splc_software="No version given",
        option_bits="0000000100000000",
        control_id="1230521030",
        release_type="Release",
        sys_par_length=120,
        max_block_length=4096,
        lsv2_flags=0x9F,
        lsv2_flags_ex=0x001F16FD,
        plc=TNC_LAYOUT,
        old_attributes=False,
        paths=LATHE_PATHS,
        ri_selectors=frozenset({21, 22, 23, 24, 25, 26, 30, 31, 32, 33, 34}),
        logins=BASE_LOGINS | {"FILEPLC", "FILESYS", "FILELOG"},
        data_paths=False,
        scope=False,
        keys=KeyStyle.NEW,
        delete_cwd_allowed=False,
        date_time=True,
        numeric_machine_parameters=False,
        lathe=True,
    ),
    "manualplus620": Profile(
        key="manualplus620",
        title="MANUALplus 620 programming station",
        model="MANUALplus 620",
        nc_software="634130 02 SP7",
        plc_software="Basic V02-07",
        splc_software="No version given",
        option_bits="0000000100000000",
        control_id="6341300200",
        release_type="Release",
        sys_par_length=120,
        max_block_length=2048,
        lsv2_flags=0x9F,
        lsv2_flags_ex=0x001F16FD,
        plc=TNC_LAYOUT,
        old_attributes=False,
        paths=LATHE_PATHS,
        ri_selectors=frozenset({21, 22, 23, 24, 25, 26, 30, 31, 32, 33, 34}),
        logins=BASE_LOGINS | {"FILEPLC", "FILESYS"},
        data_paths=False,
        scope=False,
        keys=KeyStyle.NEW,
        delete_cwd_allowed=False,
        date_time=True,
        numeric_machine_parameters=False,
        lathe=True,
        max_buffer=2048,
    ),
}


def get_profile(key: str) -> Profile:
    """Look a profile up by its key (``tnc640``, ``itnc530`` …); InputError names the choices."""
    try:
        return PROFILES[key.lower()]
    except KeyError:
        raise InputError(f"unknown profile {key!r}; choose from {', '.join(PROFILES)}") from None
