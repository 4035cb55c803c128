; Seed 001, second programming example: waiting for signals and taking over their
; parameters (in channel 3).  Verbatim, comments left open as in the manual.
%channel1
N10 #SIGNAL [ID 110014 P[0] = 1234 CH3]
N20 M30
%channel2
N10 #SIGNAL [ID 110014 P[1] = 200 CH3]
N20 M30
%channel3
N10 P1 = 1 (Speichert Wert von Kanal 1
N20 P2 = 1 (Speichert Wert von Kanal 2
N30 XP1 YP2
N40 #WAIT [ID 110014 P[0] = P1 P[1] = P2 CH1 CH2]
N50 XP1 YP2
N60 M30
