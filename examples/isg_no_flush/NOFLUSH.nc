; Seed 002, scenario 4 without its #FLUSH: the buffer effect the seed warns of.  The
; #SIGNAL SYN sits in the buffer, which the interpolator does not start on until it is full;
; the decoder waits for that signal: neither can go on.
% kanal_1
G00 X100 Y500
G01 X250 F300
(Signal 88)
(Synchronisation auf Interp.-Ebene, Synchronisation mit Kanal 1)
#SIGNAL SYN [ID88 CH1]
(Bearbeitung)
G01 X370 Z200 F80
(Warteanforderung 88)
(Synchronisation auf Decoder-Ebene, Synchronisation mit Kanal 1)
#WAIT [ID88 CH1]
G01 X900
M30
