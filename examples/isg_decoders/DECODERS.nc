; Seed 002, scenario 1: synchronisation of two decoders in two channels.  Decoder 3 waits
; for decoder 1; decoder 1 works on without interruption.  The manual's blocks, with motion
; around them so that the timing shows: decoder 1 first waits for its own interpolator
; (#FLUSH), so its signal comes 1 s late.
%kanal_1
N10 G01 X100 F6000
N20 #FLUSH
(Signal P100) (Synchronisation auf DEC-Ebene) (Synchronisation mit Kanal 3) (Parameter V.P.SYNC)
N30 V.P.SYNC = 1000
N40 P100 = 814
N50 #SIGNAL [IDP100 P[0]= V.P.SYNC CH3]
N60 G01 X200
N70 M30
% kanal_3
(Warteanforderung 814) (Synchronisation auf DEC-Ebene) (Synchronisation mit Kanal 1) (Parameter V.P.SIGNAL)
N10 #WAIT [ID814 P[0]= V.P.SIGNAL CH1]
N20 G01 XV.P.SIGNAL F60000
N30 M30
