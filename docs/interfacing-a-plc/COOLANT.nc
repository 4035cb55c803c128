; Coolant on before the cut (M08: before_motion), off after the return (M09: after_motion)
N10G1X10F600M08
N20G1X0M09
N30M30
