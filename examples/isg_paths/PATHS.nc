; Seed 002, scenario 3: synchronisation between interpolators in three channels.  Path 1
; waits for path 2, path 3 waits for path 2, path 2 signals to paths 1 and 3.
% kanal_1
N10 G01 X100 F6000
(Warteanforderung 100) (Sync. auf Interp.-Ebene) (Sync. mit Kanal 2)
N20 #WAIT SYN [ID100 CH2]
N30 G01 X200
N40 M30
%kanal_2
N10 G01 X200 F6000
(Signal 100) (Sync. auf Interp.-Ebene) (Sync. mit Kanal 1 und 3)
N20 #SIGNAL SYN [ID100 CH1 CH3]
N30 G01 X300
N40 M30
% kanal_3
N10 G01 X50 F6000
(Warteanforderung 100) (Sync. auf Interp.-Ebene) (Sync. mit Kanal 2)
N20 #WAIT SYN [ID100 CH2]
N30 G01 X150
N40 M30
