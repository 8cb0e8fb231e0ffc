%
O0022 (FACE WITH MIST)
(Written for the opendnc tests: a Fanuc lathe whose builder adds M codes)
(M07 mist coolant, M40 neutral gear: a Fanuc takes any M code)
G21 G40 G99
T0101
G50 S2000
G96 S180 M3
M7
G0 X52. Z2.
G1 Z0. F0.2
X-1.6
G0 Z2.
M9
M5
M40
G28 U0. W0.
M30
%
