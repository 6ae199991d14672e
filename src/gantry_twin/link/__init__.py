"""The live link over OPC UA: the twin served as a machine (:mod:`.server`, ``gantry-twin serve``) and the twin
following a running machine (:mod:`.shadow`, ``gantry-twin monitor --opcua``); the sample blocks both speak
(:mod:`.blocks`), the address space (:mod:`.address_space`) and who may connect (:mod:`.security`).
docs/live-link.md. Depends on the core, ``health/`` and ``run``; nothing below imports it."""
