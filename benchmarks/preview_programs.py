"""Programs for the preview's benchmark, tests and screenshots (written for them, not taken
from anywhere): a Haas mould-style job of about N moves and a small Klartext part with a
stock (BLK FORM).

The G-code job has what a backplot must show: a facing pass (tool 1), a 3D surface raster of
short moves (tool 2, most of the moves), circular pockets with a helical entry and full
circles (tool 3), and a grid of drilled holes as a G81 cycle (tool 4), with rapids between.
"""

from __future__ import annotations

import math

__all__ = ["klartext_part", "milling_program"]


def milling_program(moves: int = 100_000) -> str:
    """A Haas program (mm) of about ``moves`` moves."""
    out = ["%", "O02000 (PREVIEW BENCH)", "G21 G17 G40 G49 G80 G90"]

    def tool(number: int, speed: int) -> None:
        out.extend(
            [
                "G28 G91 Z0.",
                "G90",
                f"T{number} M06",
                f"G00 G54 X0. Y0. S{speed} M03",
                f"G43 H{number:02d} Z25.",
            ]
        )

    # tool 1: facing, zig-zag over 200 x 120 at Z0
    tool(1, 1200)
    out += ["G00 X-30. Y0.", "G01 Z0. F800."]
    for i, y in enumerate(range(0, 121, 20)):
        x0, x1 = (-30, 230) if i % 2 == 0 else (230, -30)
        out += [f"G01 X{x0}. Y{y}.", f"X{x1}."]
    out.append("G00 Z25.")
    # tool 3: eight circular pockets, helical entry then widening full circles
    tool(3, 4000)
    for k in range(8):
        cx, cy = 25 + 50 * (k % 4), 30 + 60 * (k // 4)
        out += [f"G00 X{cx + 4}. Y{cy}.", "Z2.", "G01 Z0. F300."]
        for turn in range(1, 5):
            out.append(f"G03 X{cx + 4}. Y{cy}. I-4. J0. Z{-turn * 1.5:.1f}")
        for r in range(6, 19, 3):
            out += [f"G01 X{cx + r}. Y{cy}.", f"G03 X{cx + r}. Y{cy}. I{-r}. J0."]
        out += ["G00 Z25."]
    # tool 4: a drilled grid of holes
    tool(4, 2500)
    out += ["G00 X5. Y5.", "G81 G99 Z-12. R2. F150."]
    for j in range(6):
        for i in range(20):
            x = 5 + 10 * (i if j % 2 == 0 else 19 - i)
            out.append(f"X{x}. Y{5 + 22 * j}.")
    out += ["G80", "G00 Z25."]
    # tool 2: a 3D surface raster over the rest of the budget
    tool(2, 9000)
    used = len(out)
    passes = max(2, int(math.sqrt(max(moves - used, 100) / 2)))
    steps = max(2, (moves - used) // passes)
    out += ["G00 X0. Y0.", "G01 Z0. F1500."]
    for p in range(passes):
        y = 120 * p / (passes - 1)
        forward = p % 2 == 0
        for s in range(steps + 1):
            x = 200 * (s if forward else steps - s) / steps
            z = -6 + 3 * math.sin(x / 23) * math.cos(y / 17) + 1.5 * math.sin((x + y) / 41)
            out.append(f"X{x:.3f} Y{y:.3f} Z{z:.3f}" if s == 0 else f"X{x:.3f} Z{z:.3f}")
    out += ["G00 Z25.", "M05", "G28 G91 Z0.", "M30", "%"]
    return "\n".join(out) + "\n"


def klartext_part() -> str:
    """A small Heidenhain conversational part: stock, a contour with arcs, and holes."""
    body = [
        "BEGIN PGM BRACKET MM",
        "BLK FORM 0.1 Z X+0 Y+0 Z-20",
        "BLK FORM 0.2 X+120 Y+80 Z+0",
        "TOOL CALL 5 Z S3500 F400",
        "L Z+50 R0 FMAX M3",
        "L X-10 Y-10 R0 FMAX",
        "L Z-5 R0 F300",
        "L X+10 Y+10 RL F400",
        "L X+90",
        "CC X+90 Y+30",
        "C X+110 Y+30 DR+",
        "L Y+60",
        "RND R8",
        "L X+60 Y+70",
        "CT X+30 Y+60",
        "L X+10 Y+40",
        "CHF 4",
        "L Y+10",
        "L X-10 Y-10 R0 FMAX",
        "L Z+50 R0 FMAX",
        "TOOL CALL 7 Z S2200 F200",
        "CYCL DEF 200 DRILLING Q200=+2 Q201=-15 Q206=+150 Q202=+5 Q210=+0 Q203=+0 Q204=+50 Q211=+0",
        "L X+30 Y+30 R0 FMAX M3",
        "CYCL CALL",
        "L X+60 Y+30 R0 FMAX M99",
        "L X+60 Y+50 R0 FMAX M99",
        "L Z+100 R0 FMAX M30",
        "END PGM BRACKET MM",
    ]
    return "\n".join(f"{n} {line}" for n, line in enumerate(body)) + "\n"
