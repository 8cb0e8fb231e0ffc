%
O01006 (CLASS 3 POCKET)
(Written for the opendnc tests: a hand-written class program, incremental moves)
G20 G17 G40 G49 G80 G90
T1 M06
G00 G54 X1. Y1.
S2500 M03
G43 H01 Z0.1 M08
G01 Z-0.1 F5.
G91 X2. F12.
Y1.5
X-2.
Y-1.5
G90 G01 X1.5 Y1.5
G91 G02 X0.5 Y0. I0.25 J0.
G90 G00 Z1.
M05
M09
G28 G91 Z0.
G90
M30
%
