; HAZ2 - process 2: waits twice for process 1
N1(WAI,1)
N2(WAI,1)
N3M30
