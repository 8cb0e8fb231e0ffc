"""Screen dump of the virtual TNC: a real 8-bit BMP of a status screen.

The picture shows the operating mode, the selected program, axis positions, overrides,
spindle, tool and the first NC error, drawn with a tiny built-in 3x5 font, so a client that
fetches the dump sees the machine state it has just read over LSV2.
"""

from __future__ import annotations

import struct

from opendnc.sim.tnc.machine import Machine

WIDTH, HEIGHT = 640, 480
SCALE = 3
# Palette index -> (r, g, b)
PALETTE = [
    (0, 0, 0),
    (235, 235, 235),  # 1 background
    (40, 40, 40),  # 2 text
    (0, 84, 150),  # 3 header bar (Heidenhain-ish blue)
    (255, 255, 255),  # 4 header text
    (200, 0, 0),  # 5 error
    (0, 150, 60),  # 6 ok / bars
    (180, 180, 180),  # 7 frames
]

# 3x5 glyphs, rows top to bottom, 3 bits each (1 = ink).
_GLYPHS = {
    "0": "111101101101111", "1": "010110010010111", "2": "111001111100111",
    "3": "111001111001111", "4": "101101111001001", "5": "111100111001111",
    "6": "111100111101111", "7": "111001010010010", "8": "111101111101111",
    "9": "111101111001111", "A": "010101111101101", "B": "110101110101110",
    "C": "011100100100011", "D": "110101101101110", "E": "111100110100111",
    "F": "111100110100100", "G": "011100101101011", "H": "101101111101101",
    "I": "111010010010111", "J": "001001001101010", "K": "101101110101101",
    "L": "100100100100111", "M": "101111111101101", "N": "110101101101101",
    "O": "010101101101010", "P": "110101110100100", "Q": "010101101110011",
    "R": "110101110101101", "S": "011100010001110", "T": "111010010010010",
    "U": "101101101101111", "V": "101101101101010", "W": "101101111111101",
    "X": "101101010101101", "Y": "101101010010010", "Z": "111001010100111",
    ".": "000000000000010", ",": "000000000010100", ":": "000010000010000",
    "-": "000000111000000", "+": "000010111010000", "%": "101001010100101",
    "/": "001001010100100", "\\": "100100010001001", "_": "000000000000111",
    "$": "011110010011110", "(": "010100100100010", ")": "010001001001010",
    "=": "000111000111000", "!": "010010010000010", "#": "101111101111101",
}  # fmt: skip


class Canvas:
    """An 8-bit palette image with rectangle and text drawing."""

    def __init__(self, width: int, height: int, background: int) -> None:
        self.width, self.height = width, height
        self.pixels = bytearray([background]) * (width * height)

    def rect(self, x: int, y: int, w: int, h: int, color: int) -> None:
        """Fill a rectangle (clipped)."""
        x0, y0 = max(0, x), max(0, y)
        x1, y1 = min(self.width, x + w), min(self.height, y + h)
        if x1 <= x0:
            return
        row = bytes([color]) * (x1 - x0)
        for yy in range(y0, y1):
            start = yy * self.width + x0
            self.pixels[start : start + len(row)] = row

    def text(self, x: int, y: int, text: str, color: int, scale: int = SCALE) -> None:
        """Draw upper-cased text with the 3x5 font."""
        for ch in text.upper():
            glyph = _GLYPHS.get(ch)
            if glyph is not None:
                for i, bit in enumerate(glyph):
                    if bit == "1":
                        self.rect(x + (i % 3) * scale, y + (i // 3) * scale, scale, scale, color)
            x += 4 * scale

    def to_bmp(self) -> bytes:
        """Encode as an uncompressed 8-bit Windows BMP (bottom-up rows)."""
        row_len = (self.width + 3) & ~3
        pixel_bytes = row_len * self.height
        palette = b"".join(struct.pack("<BBBB", b, g, r, 0) for r, g, b in PALETTE)
        palette += b"\0\0\0\0" * (256 - len(PALETTE))
        offset = 14 + 40 + len(palette)
        header = struct.pack("<2sIHHI", b"BM", offset + pixel_bytes, 0, 0, offset)
        info = struct.pack(
            "<IiiHHIIiiII", 40, self.width, self.height, 1, 8, 0, pixel_bytes, 2835, 2835, 256, 0
        )
        pad = b"\0" * (row_len - self.width)
        rows = [
            bytes(self.pixels[y * self.width : (y + 1) * self.width]) + pad
            for y in range(self.height - 1, -1, -1)
        ]
        return header + info + palette + b"".join(rows)


def render_status(machine: Machine) -> bytes:
    """A BMP of the machine's status screen as it is right now."""
    machine.advance()
    c = Canvas(WIDTH, HEIGHT, 1)
    c.rect(0, 0, WIDTH, 36, 3)
    c.text(10, 10, f"{machine.profile.model}  {machine.screen}", 4)
    c.text(10, 48, f"PGM {machine.main_program or '-'}", 2)
    c.text(10, 72, f"BLOCK {machine.current_line}  STATE {machine.program_state.name}", 2)
    y = 110
    for axis, value in machine.positions.items():
        c.rect(8, y - 4, 300, 26, 7)
        c.text(16, y, f"{axis} {value:+10.3f}", 2)
        y += 32
    bars = [
        ("F%", machine.feed_override),
        ("S%", machine.spindle_override),
        ("FMAX%", machine.rapid_override),
    ]
    for i, (label, value) in enumerate(bars):
        yy = 110 + i * 32
        c.text(340, yy, label, 2)
        c.rect(440, yy, 180, 18, 7)
        c.rect(440, yy, min(180, value * 180 // 15000), 18, 6)
    c.text(340, 220, f"T {machine.tool}  S {machine.spindle_speed}", 2)
    c.text(340, 246, "SPINDLE ON" if machine.spindle_on else "SPINDLE OFF", 6)
    c.text(340, 272, f"PARTS {machine.part_counter}", 2)
    if machine.errors:
        c.rect(0, HEIGHT - 40, WIDTH, 40, 5)
        c.text(10, HEIGHT - 30, machine.errors[0].text[:48], 4)
    return c.to_bmp()
