(dexmon example: pocket, helical bore and outside contour with arcs)
(stock: box X0..60 Y0..40 Z0..20, work zero at its lower-left bottom corner)
(tool: T1 flat end mill, diameter 6 mm)
(dexmon simulate monitor/examples/pocket.nc --stock box:0,0,0,60,40,20 --tool flat:6 --resolution 0.2)
G21 G90 G17 G94
T1 M6
S12000 M3
G0 Z25
(pocket X10..50 Y10..30, two levels)
G0 X13 Y13
G0 Z21
G1 Z17.5 F200
F900
G1 X47 Y13
G1 Y17
G1 X13
G1 Y21
G1 X47
G1 Y25
G1 X13
G1 Y27
G1 X47
G1 X13
G1 Y13
G1 Z15 F200
F900
G1 X47 Y13
G1 Y17
G1 X13
G1 Y21
G1 X47
G1 Y25
G1 X13
G1 Y27
G1 X47
G1 X13
G1 Y13
(helical bore, 10 mm hole at X30 Y20 down to Z10)
G0 Z16
G0 X32 Y20
G1 Z15 F200
G2 X32 Y20 Z12.5 I-2 J0 F400
G2 X32 Y20 Z10 I-2 J0
G2 X32 Y20 I-2 J0
G1 X30 Y20
G0 Z25
(outside contour 3 mm deep, part corners rounded R5)
G0 X8 Y-5
G0 Z21
G1 Z17 F200
F800
G1 X8 Y0
G1 X52 Y0
G3 X60 Y8 I0 J8
G1 X60 Y32
G3 X52 Y40 I-8 J0
G1 X8 Y40
G3 X0 Y32 I0 J-8
G1 X0 Y8
G3 X8 Y0 I8 J0
G1 X8 Y-5
G0 Z25
M5
M30
