"""The turntable: the servo and its motion profile (:mod:`.servo`), Dynamixel register units
(:mod:`.units`), MuJoCo physics with jitter (:mod:`.dynamics`), the encoder (:mod:`.encoder`), the
``[turntable]`` settings (:mod:`.options`), the motions a scan runs (:mod:`.motion`), the interface of a
table driven line by line (:mod:`.table`) and the stability matrix (:mod:`.stability`)."""
