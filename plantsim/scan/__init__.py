"""A scan: its schedule (:mod:`.schedule`), configuration (:mod:`.config`), the plan of which parts
run and what is refused (:mod:`.plan`), the raw record (:mod:`.raw`), the pipeline (:mod:`.pipeline`),
and the line-by-line session of a rig scan with its journal (:mod:`.session`, :mod:`.journal`)."""
