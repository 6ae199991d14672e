"""The machine as it is: the compiled MJCF gantry and its true theta (:mod:`.model`), the rig's static offset and
force ripple (:mod:`.effects`), Coulomb and LuGre friction (:mod:`.friction`), plant changes during a run
(:mod:`.faults`) and the encoder that measures it (:mod:`.sensing`). A new plant effect goes here."""
