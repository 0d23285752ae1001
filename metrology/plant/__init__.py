"""Results where the plant reads them, live: an OPC UA server after OPC 40210 (GMS) for
``metro measure --opcua`` (:mod:`metrology.plant.server`, its address space :mod:`metrology.plant.gms`).
Needs the ``plant`` extra (asyncua), imported only when a server starts."""
