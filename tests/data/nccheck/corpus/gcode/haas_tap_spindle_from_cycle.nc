%
O02023 (TAP M8, SPINDLE STARTED BY G84)
(Written for the opendnc tests: a Haas mill rigid tap with no M03 before the cycle)
(Haas G84: the control starts the spindle CW itself; S comes before the cycle)
(T3 | M8X1.25 TAP | H3)
G21 G90 G17 G40 G49 G80
T3 M06
S500
G00 G54 X20. Y20.
G43 H03 Z10. M08
G98 G84 Z-12. R5. F625.
X40.
G80
M09
G28 G91 Z0.
G90
M30
%
