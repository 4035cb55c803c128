; Seed 002, scenario 2: synchronisation between decoder and interpolators in three channels.
; Interpolator 1 waits for interpolator 2 and decoder 3; interpolator 2 waits for
; interpolator 1 and decoder 3; decoder 3 signals to interpolators 1 and 2.  The manual shows
; only the WAITs of channels 1 and 2; their #SIGNAL SYN to each other is written here.
%kanal_1
N10 G01 X100 F6000
N20 #SIGNAL SYN [ID968 CH2]
(Warteanforderung 968) (Sync. auf Interp.-Ebene) (Sync. mit Kanal 2 und 3)
N30 #WAIT SYN [ID968 CH2 CH3]
N40 G01 X200
N50 M30
%kanal_2
N10 G01 X300 F6000
N20 #SIGNAL SYN [ID968 CH1]
(Wartenaforderung 968) (Sync. auf Interp.-Ebene) (Sync. mit Kanal 3 und 1)
N30 #WAIT SYN [ID968 CH3 CH1]
N40 G01 X400
N50 M30
% kanal_3
N10 G01 X50 F6000
N15 #FLUSH
(Signal 968) (Sync. auf Decoder-Ebene) (Sync. mit Kanal 1 und 2)
N20 #SIGNAL [ID968 CH1 CH2]
N30 M30
