%
O0021 (GEAR RANGE AND MIST)
(Written for the opendnc tests: a Fanuc mill whose builder adds M codes)
(M40/M41 low and high gear range, M07 mist coolant; a Fanuc takes any M code)
(T2 | 10MM FLAT ENDMILL | H2 | D2)
G21
G0 G17 G40 G49 G80 G90
T2 M6
M41
G0 G90 G54 X-10. Y-10. S1200 M3
G43 H2 Z25. M7
Z2.
G1 Z-3. F150.
X60.
Y40.
X-10.
Y-10.
G0 Z25.
M9
M5
M40
G91 G28 Z0.
M30
%
