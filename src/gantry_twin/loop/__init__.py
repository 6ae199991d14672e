"""The compiled 0.2 ms loop: one sample written once (:mod:`.sample`), the driver that runs it in chunks on the
compiled or the reference backend (:mod:`.simulate`), what a run records and who may watch it (:mod:`.trace`),
and the end-stop and saturation events read from a trace (:mod:`.events`). The loop runs any controller and any
contour through their protocols; it names none."""
