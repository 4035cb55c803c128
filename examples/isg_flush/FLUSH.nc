; Seed 002, scenario 4: synchronisation between decoder and interpolator of one channel.  The
; decoder waits until the interpolator has reached X250; "G01 X370 Z200 F80" is already in
; the channel, "G01 X900" is decoded only after the synchronisation.  Verbatim.
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
#FLUSH
#WAIT [ID88 CH1]
G01 X900
M30
