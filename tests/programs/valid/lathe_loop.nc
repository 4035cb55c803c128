; a realistic process-1 program: tool change, arcs, a counted loop, E arithmetic, dwell
"TOP"
N10 T1.1 M6 S1200 F300
N20 G0 X0 Y0 Z5
N30 E1=0
N40 (RPT,3)
N50   G1 Z-1.5 F150
N60   G2 X20 Y0 I10 J0
N70   G3 X0 Y0 I-10 J0
N80   E1=E1+1
N90 (ERP)
N100 (DLY,0.5)
N110 E2=SQR(ABS(E1*E1-2))+ATN(1)*INT(2.7)
N120 (DIS,"passes done",E1)
N130 (BLE,E1,2,TOP)
/N140 M0
N150 G0 Z50 ; retract
N160 M30
