; Seed 001, first programming example: the three kinds of #WAIT, in channel 1 (the manual's
; comments joined onto one line each), with channels 2 and 3 written to answer them.
%channel1
(Wartemarke 4711, Synchronisation auf DEC-Ebene, SIGNAL 4711 von beliebigem Kanal)
N200 #WAIT [ID4711]
N210 G01 X50 F6000
(Wartemarke 815, Synchronisation auf Interpolator-Ebene, SIGNAL 815 von Kanal 2 und 3)
N100 #WAIT SYN [ID815 CH2 CH3]
(Wartemarke 911, Synchronisation auf Decoder-Ebene, von Kanal 3)
(1.Signalparameter V.P.SIGNAL, 2.Signalparameter P200)
N250 P100 = 911
N300 #WAIT [IDP100 P[0]=V.P.SIGNAL P[1]=P200 CH3]
(Nachfolgende Berechnung findet erst nach Eintreffen)
(des Signals statt)
N350 P20 = 10 * P200
N360 G01 XP20 YV.P.SIGNAL
N400 M30
%channel2
N10 G01 X300 F6000
N20 #SIGNAL SYN [ID815 CH1]
N30 M30
%channel3
N10 G01 X200 F6000
N15 #FLUSH
N20 #SIGNAL [ID4711]
N30 #SIGNAL SYN [ID815 CH1]
N40 #SIGNAL [ID911 P[0]=7 P[1]=12 CH1]
N50 M30
