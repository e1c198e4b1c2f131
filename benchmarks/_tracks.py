"""The track of the low-level benchmarks' recorded figures.

``wfjax.Track()`` was a 24-bay track with absorbing ends until 2026-12-06; since then it is
the least track (4 bays) with end networks, which a :class:`wfjax.Scenario` lengthens to what
its wheels and sensors need. A benchmark that builds models from a ``Track`` directly
(modal models, loop structures, contact tables, receptances) would run on those 4 bays, so
the scripts whose figures were recorded on the old default name it: ``wf.Track(**RECORDED)``.
"""

RECORDED = {"n_bays": 24, "ends": "absorbing"}
