; HAZ1 - process 1: a plain SND and a # SND behind a move of one second
N1(EXE,2,HAZ2)
N2G1X100F6000
N3(SND,2)
N4#(SND,2)
N5M30
