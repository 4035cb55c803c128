; PART - machine one part (process 1).  The PLC (plc.st) runs the machine; this program asks
; with M codes and waits for the PLC's interlock bits (names: ncgate.toml's [symbols]).
N10(WAI,SA33=1)      ; door_ready: the door is closed and locked
N20(WAI,SA30=1)      ; clamped
N30T2M06             ; tool 2: the NC waits for the PLC's acknowledge of M06 ([nc.aux])
N40S6000M03          ; spindle on
N50(WAI,SA31=1)      ; spindle_ready: at speed
N60M08               ; coolant on
N70(WAI,SA32=1)      ; coolant_ready: pressure up
N80G1X100F3000       ; the cut
N90G1Y50
N100G1X0
N110G0Y0
N120M09              ; coolant off
N130(WAI,SA32=0)
N140M05              ; spindle off
N150(WAI,SA34=1)     ; spindle_halted: at standstill
N160SYVAR21=1M30     ; part_done: the part is finished (the PLC counts it as P1 ends)
