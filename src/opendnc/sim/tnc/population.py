"""Default content of a fresh programming station: demo programs, MDI, tool and pocket tables.

Where each family keeps what is described in docs/tnc-profiles.md#fresh-roots.

Tables use the fixed-width text format of the controls: a ``BEGIN`` line, a header line whose
column positions define the widths, one row per line and ``[END]``.
"""

from __future__ import annotations

from opendnc.lsv2.tables import Column, Table, fixed_columns
from opendnc.sim.tnc.filesystem import ControlFs, WirePath
from opendnc.sim.tnc.profiles import Profile

MARKER = ".populated"


TOOL_COLUMNS = fixed_columns(
    ("T", 6),
    ("NAME", 17),
    ("L", 12),
    ("R", 12),
    ("R2", 12),
    ("DL", 9),
    ("DR", 9),
    ("DR2", 9),
    ("LCUTS", 9),
    ("ANGLE", 8),
    ("TL", 3),
    ("RT", 5),
    ("TIME1", 6),
    ("CUR_TIME", 9),
    ("DOC", 17),
)
POCKET_COLUMNS = fixed_columns(
    ("P", 8),
    ("T", 6),
    ("TNAME", 17),
    ("ST", 3),
    ("F", 3),
    ("L", 3),
    ("DOC", 17),
)

_TOOLS = [
    ("NULLWERKZEUG", 0.0, 0.0, "zero tool"),
    ("MILL_D10_ROUGH", 65.0, 5.0, "end mill 10"),
    ("MILL_D6_FINISH", 50.0, 3.0, "end mill 6"),
    ("DRILL_D8", 90.0, 4.0, "twist drill 8"),
    ("CENTER_D6", 45.0, 3.0, "spot drill 90deg"),
    ("BALL_D4", 40.0, 2.0, "ball nose 4"),
    ("TAP_M8", 70.0, 4.0, "tap M8x1.25"),
    ("FACE_D50", 55.0, 25.0, "face mill 50"),
]


def render_table(title: str, columns: list[Column], rows: list[dict[str, str]]) -> str:
    """A complete fixed-width table file (written by the client's table model)."""
    return Table(f"BEGIN {title} MM", columns, rows).to_text()


def tool_table(file_name: str) -> str:
    """A tool table with a handful of realistic tools."""
    rows = []
    for number, (name, length, radius, doc) in enumerate(_TOOLS):
        rows.append(
            {
                "T": str(number),
                "NAME": name,
                "L": f"{length:+.4f}",
                "R": f"{radius:+.4f}",
                "R2": "+0",
                "DL": "+0",
                "DR": "+0",
                "DR2": "+0",
                "LCUTS": "0",
                "ANGLE": "0",
                "TL": "",
                "RT": "",
                "TIME1": "0",
                "CUR_TIME": "0",
                "DOC": doc,
            }
        )
    return render_table(file_name.upper(), TOOL_COLUMNS, rows)


def pocket_table(file_name: str) -> str:
    """Pocket table: tools 1..7 sit in pockets 1..7, the spindle pocket is 0."""
    rows = [
        {
            "P": f"1.{p}" if p else "0.0",
            "T": str(p) if p < len(_TOOLS) else "",
            "TNAME": _TOOLS[p][0] if p < len(_TOOLS) else "",
            "ST": "",
            "F": "",
            "L": "",
            "DOC": "",
        }
        for p in range(12)
    ]
    return render_table(file_name.upper(), POCKET_COLUMNS, rows)


def klartext_demo(name: str, call: str | None = None) -> str:
    """A conversational (Klartext) demo program that actually moves axes (and may call one)."""
    body = [
        f"BEGIN PGM {name} MM",
        "BLK FORM 0.1 Z X+0 Y+0 Z-20",
        "BLK FORM 0.2 X+100 Y+100 Z+0",
        "TOOL CALL 1 Z S3000 F600",
        "L Z+50 R0 FMAX M3",
        "L X+10 Y+10 R0 FMAX",
        "L Z-5 F300",
        "L X+90 F600",
        "L Y+90",
        "L X+10",
        "L Y+10",
        "L Z+50 FMAX",
        "TOOL CALL 3 Z S2500 F200",
        "L X+50 Y+50 FMAX",
        "L Z-15 F200",
        "L Z+50 FMAX M9",
        *([f"CALL PGM {call}"] if call else []),
        "M30",
        f"END PGM {name} MM",
    ]
    return "\r\n".join(f"{i} {line}" for i, line in enumerate(body)) + "\r\n"


def iso_demo(number: int) -> str:
    """An ISO (DIN/ISO) demo program."""
    body = [
        f"%{number} G71 *",
        "N10 G30 G17 X+0 Y+0 Z-20 *",
        "N20 G31 G90 X+100 Y+100 Z+0 *",
        "N30 T2 G17 S4000 *",
        "N40 G00 G40 G90 Z+50 M03 *",
        "N50 X+20 Y+20 *",
        "N60 G01 Z-3 F250 *",
        "N70 X+80 F500 *",
        "N80 Y+80 *",
        "N90 X+20 *",
        "N100 Y+20 *",
        "N110 G00 Z+50 M05 *",
        "N120 M30 *",
        f"N99999999 %{number} G71 *",
    ]
    return "\r\n".join(body) + "\r\n"


def lathe_demo() -> str:
    """A smart.Turn / DIN PLUS style lathe program."""
    return (
        "%PGM01.nc\r\n"
        "HEADER\r\n"
        "TURRET 1\r\n"
        'T1 ID"ROUGH_80"\r\n'
        "MACHINING\r\n"
        "N1 T1 G96 S200 G95 F0.3 M3\r\n"
        "N2 G0 X60 Z2\r\n"
        "N3 G1 Z-40\r\n"
        "N4 G1 X80\r\n"
        "N5 G0 Z2\r\n"
        "END\r\n"
    )


def lathe_subprogram() -> str:
    """A DIN subprogram (``.ncs``) of the kind a lathe's main programs call."""
    return "%GROOVE.ncs\r\nMACHINING\r\nN1 G0 X62 Z-20\r\nN2 G1 X54 F0.08\r\nN3 G0 X62\r\nEND\r\n"


def lathe_klartext_demo(name: str) -> str:
    """A conversational program in X and Z only (the lathe station's ``.H`` example)."""
    body = [
        f"BEGIN PGM {name} MM",
        "TOOL CALL 1 Z S1500 F200",
        "L X+60 Z+2 R0 FMAX M3",
        "L Z-30 F150",
        "L X+70",
        "L Z+2 FMAX M5",
        "M30",
        f"END PGM {name} MM",
    ]
    return "\r\n".join(f"{i} {line}" for i, line in enumerate(body)) + "\r\n"


def populate(fs: ControlFs, profile: Profile) -> None:
    """Fill a fresh root like a new programming station (only once per root)."""
    # One marker per family: a root first used by another family still gets this one's
    # well-known files, but nothing a user deleted comes back on the next start.
    marker = fs.state_dir / f"{MARKER}-{profile.key}"
    if marker.exists():
        return
    root = WirePath("TNC:", ())
    paths = profile.paths

    def ensure_dir(text: str) -> WirePath:
        wp = fs.parse(text, root)
        for i in range(1, len(wp.parts) + 1):
            sub = WirePath(wp.drive, wp.parts[:i])
            if not fs.is_dir(sub):
                fs.mkdir(sub)
        return wp

    def put(text: str, content: str) -> None:
        wp = fs.parse(text, root)
        ensure_dir(str(wp.parent))
        if not fs.host_path(wp).exists():
            fs.write_atomic(wp, content.encode("latin-1"))

    prog = paths.program_dir.rstrip("\\")
    if profile.lathe:
        put(paths.mdi_program, lathe_demo())
        put(prog + "\\DEMO_SHAFT.nc", lathe_demo().replace("PGM01", "DEMO_SHAFT"))
        put(prog + "\\demo\\FLANGE.nc", lathe_demo().replace("PGM01", "FLANGE"))
        put(prog + "\\GROOVE.ncs", lathe_subprogram())
        # The program types docs/tnc-profiles.md#paths-and-drives names (conversational .H,
        # ISO .I) are in ncps too, so a client's file search for them finds one of each there
        # (docs/tnc-profiles.md#fresh-roots says why).
        put(prog + "\\SHAFT.H", lathe_klartext_demo("SHAFT"))
        put(prog + "\\2001.I", iso_demo(2001))
    else:
        # Sub-folder programs live in the project folder where the family has one (iTNC 530:
        # TNC:\nc_prog next to the programs in TNC:\), else in the program folder itself.
        projects = (paths.project_dir or prog).rstrip("\\")
        frame = "demo\\FRAME.H" if paths.project_dir is None else projects + "\\demo\\FRAME.H"
        put(paths.mdi_program, "0 BEGIN PGM $MDI MM\r\n1 END PGM $MDI MM\r\n")
        put(prog + "\\POCKET.H", klartext_demo("POCKET", call=frame))
        put(prog + "\\1001.I", iso_demo(1001))
        put(projects + "\\demo\\FRAME.H", klartext_demo("FRAME"))
        put(projects + "\\demo\\CONTOUR.H", klartext_demo("CONTOUR"))
    tool_name = paths.tool_table.rsplit("\\", 1)[1]
    pocket_name = paths.pocket_table.rsplit("\\", 1)[1]
    put(paths.tool_table, tool_table(tool_name))
    put(paths.pocket_table, pocket_table(pocket_name))
    if profile.paths.program_dir != "TNC:\\":
        ensure_dir("TNC:\\table")
    if "PLC:" in profile.drives:
        put("PLC:\\PLCMAIN.SRC", ";PLC main program\r\nL M4000\r\n= M4001\r\nEM\r\n")
        put("PLC:\\OEM.SYS", "PLCPATH= PLC:\\PLCMAIN.SRC\r\nREMOTE.LOCKSOFTKEYVISIBLE= 1\r\n")
    if "SYS:" in profile.drives:
        put("SYS:\\version.txt", f"{profile.model} {profile.nc_software}\r\n")
    if "LOG:" in profile.drives:
        put("LOG:\\errlog.txt", "Error log\r\n")
        # OEM Python applications log below LOG:\oem\python (read by field clients as FILEPLC).
        put("LOG:\\oem\\python\\python.log", f"{profile.model} OEM Python log\r\n")
    marker.write_text(profile.key)
