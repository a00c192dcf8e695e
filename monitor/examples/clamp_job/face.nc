(dexmon bundled example: face a 60 x 40 x 20 block down 5 mm to Z-5; work zero at the lower-left corner of its top face)
(tool T1: 6 mm flat end mill; a clamp stands left of the block)
(two faults are planted on purpose: a gouge on line 22 and a rapid through the stock on line 36)
G21 G90 G17 G94
G54
T1 M6
S10000 M3
G0 Z5
G0 X-8 Y2
G0 Z-5
G1 X68 F1200
G1 Y6
G1 X-8
G1 Y10
G1 X68
G1 Y14
G1 X-8
G1 Y18
G1 X68
G1 Y22
G1 X34
G1 X30 Z-5.5 (planted gouge: dips 0.5 mm into the design)
G1 X26 Z-5
G1 X-8
G1 Y26
G1 X68
G1 Y30
G1 X-8
G1 Y34
G1 X68
G1 Y38
G1 X-8
G0 Z5
G0 Y1
G0 Z-10
G0 X68 (planted fault: rapid through the stock)
G0 Z5
M5
M30
