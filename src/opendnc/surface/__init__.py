"""Surface model: probe a grid on a Haas, capture the DPRNT lines, report the surface.

The parts without numpy (grid, program generation, capture, the points file) import from
here or their own modules; the maths and the pictures (:mod:`opendnc.surface.fit`,
:mod:`opendnc.surface.render`, :mod:`opendnc.surface.report`) need the ``surface`` extra
(``pip install 'opendnc[surface]'``). See docs/surface.md.
"""

from opendnc.surface.grid import Grid, GridPoint, Units, parse_grid, parse_origin

__all__ = ["Grid", "GridPoint", "Units", "parse_grid", "parse_origin"]
