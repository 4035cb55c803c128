; every synchronisation code form of spec 1.5 that is legal in process 1
N1 (EXE,2,SUB)
N2 E4=3
N3 (EXE,E4,SUB/MP0)
N4 #(SND,2)
N5 (WAI,2)
N6 (WAI,SA10=1)
N7 (WAI,SA10.BY#2)
N8 (WAI,SK2.IN=E11)
N9 (WAI,SYVAR2>E5)
N10 (WAI,SK250<8)
N11 SYVAR2=E8
N12 M100(REL)
