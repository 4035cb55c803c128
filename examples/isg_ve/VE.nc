; Seed 004: synchronous and asynchronous V.E. access through the PLC.
N10 G01 X100 F6000
N20 P1 = V.E.PART_OK_NOW (asynchronous: read while decoding, before X100 is reached)
N30 P2 = V.E.PART_OK (synchronous: the decoder first waits for X100, an implicit #FLUSH WAIT)
N40 G01 X200
N50 V.E.LAMP = 1 (synchronous write: done when the interpolator reaches this block)
N60 V.E.LAMP_NOW = 1 (asynchronous write: done when the decoder reaches it)
N70 G01 X[200 + P1] Y[P2]
N80 M30
