"""Which G and M codes each control knows, and which the dry run does not draw.

The lists come from the public code tables of the Haas mill operator's manual (G-codes,
M-codes chapters), the Fanuc macro-B references for the common Fanuc extras, and the
Heidenhain ISO programming chapters of the TNC user manuals (docs/check.md#codes).
"""

from __future__ import annotations

from itertools import chain

__all__ = [
    "FANUC_LATHE_G",
    "FANUC_MILL_G",
    "HAAS_G",
    "HAAS_LATHE_G",
    "HAAS_LATHE_M",
    "HAAS_M",
    "HAAS_MILL_G",
    "HEIDENHAIN_M",
    "ISO_G",
    "NOT_DRAWN_G",
]


def _codes(*parts: range | tuple[float, ...]) -> frozenset[float]:
    return frozenset(float(c) for c in chain.from_iterable(parts))


HAAS_MILL_G = _codes(
    (0, 1, 2, 3, 4, 9, 10, 12, 13, 17, 18, 19, 20, 21, 28, 29, 31, 35, 36, 37),
    (40, 41, 42, 43, 44, 47, 49, 50, 51, 52, 53, 60, 61, 64, 65, 68, 69, 70, 71, 72),
    range(54, 60),
    (73, 74, 76, 77),
    range(80, 90),
    (90, 91, 92, 93, 94, 95, 98, 99, 100, 101, 102, 103, 107),
    range(110, 130),
    (136, 141, 143, 150, 153, 154, 174, 184, 187, 234, 253, 254, 255, 266, 268, 269),
)
"""G-codes of a Haas mill (Haas mill operator's manual, G-codes chapter)."""

FANUC_MILL_G = _codes(
    (0, 1, 2, 3, 4, 5, 5.1, 7.1, 8, 9, 10, 11, 12.1, 13.1, 15, 16, 17, 18, 19, 20, 21),
    (22, 23, 27, 28, 29, 30, 31, 33, 37, 39, 40, 41, 42, 43, 44, 43.4, 43.5, 49),
    (50, 51, 50.1, 51.1, 52, 53, 53.1, 54, 54.1, 55, 56, 57, 58, 59, 60, 61, 62, 63, 64),
    (65, 66, 67, 68, 68.2, 69, 73, 74, 76, 80, 81, 82, 83, 84, 85, 86, 87, 88, 89),
    (90, 91, 92, 93, 94, 95, 96, 97, 98, 99),
)
"""G-codes of a Fanuc 0i / 30i mill (M series, with the common options: G05 / G05.1
high-speed and AI contour control, G54.1 Pn additional work offsets, G68.2 tilted plane)."""

HAAS_G = HAAS_MILL_G | FANUC_MILL_G
"""G-codes a mill program may hold when its control is not named: Haas and Fanuc mills."""

HAAS_LATHE_G = _codes(
    (0, 1, 2, 3, 4, 9, 10, 14, 15, 17, 18, 19, 20, 21, 28, 29, 31, 32, 40, 41, 42),
    (50, 51, 52, 53, 54, 55, 56, 57, 58, 59, 61, 64, 65, 70, 71, 72, 73, 74, 75, 76),
    range(80, 90),
    (90, 92, 94, 95, 96, 97, 98, 99, 100, 101, 103, 105),
    range(110, 130),
    (154, 184, 186, 187, 195, 196, 198, 199, 200, 211, 212, 241, 242, 243, 245, 246, 247),
    (249, 266),
)
"""G-codes of a Haas lathe (Haas lathe operator's manual, G-codes chapter)."""

FANUC_LATHE_G = _codes(
    (0, 1, 2, 3, 4, 5, 5.1, 7.1, 9, 10, 11, 12.1, 13.1, 17, 18, 19, 20, 21, 22, 23),
    (25, 26, 27, 28, 30, 31, 32, 34, 36, 37, 40, 41, 42, 50, 50.3, 52, 53, 54, 55),
    (56, 57, 58, 59, 61, 63, 64, 65, 66, 67, 68, 69, 70, 71, 72, 73, 74, 75, 76),
    (80, 83, 84, 85, 86, 87, 88, 89, 90, 92, 94, 96, 97, 98, 99),
)
"""G-codes of a Fanuc 0i / 30i lathe (T series, G-code system A: X/Z absolute, U/W
incremental, G98/G99 feed per minute / per revolution)."""

HAAS_LATHE_M = _codes(
    range(0, 6),
    range(8, 25),
    (30, 31, 33, 36, 37, 38, 39, 41, 42, 43, 44),
    range(51, 70),
    range(76, 80),
    range(85, 100),
)
"""M-codes of a Haas lathe below M100 (M100 and up: options and user M codes)."""

HAAS_M = _codes(
    range(0, 14),
    (16, 17, 18, 19, 21, 22, 23, 30, 31, 33, 34, 35, 36, 39, 41, 42, 46, 48, 49),
    range(50, 70),
    range(75, 90),
    # M29: Fanuc rigid tapping mode (the mill table of a program whose control is not named)
    (29, 95, 96, 97, 98, 99, 104, 105, 109, 110, 119),
    range(121, 140),
    (143, 144, 145, 146, 149, 150, 155, 158, 159),
)
"""M-codes of a Haas mill (user M-codes M121-M129 included)."""

ISO_G = _codes(
    (0, 1, 2, 3, 4, 5, 6, 7, 10, 11, 12, 13, 15, 16, 17, 18, 19, 20, 24, 25, 26, 27),
    (28, 29, 30, 31, 37, 38, 39, 40, 41, 42, 43, 44, 50, 51, 53, 54, 55, 56, 60, 70, 71),
    (73, 74, 75, 76, 77, 78, 79, 80, 83, 84, 85, 86, 87, 88, 89, 90, 91, 98, 99),
    range(200, 300),
)
"""G-codes of a Heidenhain TNC in ISO programs (cycles G200-G299 included)."""

HEIDENHAIN_M = _codes(
    (0, 1, 2, 3, 4, 5, 6, 8, 9, 13, 14, 30, 89, 90, 91, 92, 94, 97, 98, 99),
    range(101, 151),
)
"""M functions of a Heidenhain TNC (conversational and ISO)."""

NOT_DRAWN_G = _codes(
    (12, 13, 47, 50, 51, 68, 68.2, 70, 71, 72, 100, 101, 107, 150, 234, 254),
)
"""G-codes the dry run accepts but does not turn into moves (a warning says so)."""

MOTION = frozenset((0.0, 1.0, 2.0, 3.0))
CYCLES = _codes((73, 74, 76, 77), range(81, 90))
LATHE_CYCLES = _codes(range(81, 90))
"""Drilling cycles of a lathe (along Z, live tooling or at the centre): drawn as holes."""
LATHE_CONTOUR = _codes((70, 71, 72, 73))
"""Lathe finishing and roughing cycles whose P..Q blocks are the contour."""
LATHE_NOT_DRAWN = _codes((74, 75, 76, 90, 92, 94))
"""Lathe grooving, threading and single-pass cycles: run, not drawn (the tool comes back)."""
FEED_RETRACT = _codes((74, 84, 85, 88, 89))
"""Canned cycles that leave the hole at the feed rate (tapping, reaming, boring)."""
