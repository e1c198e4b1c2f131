"""The program core: a :class:`wfjax.scenario.description.Scenario` compiled into a
:class:`~wfjax.program.core.Program` and run over a grid of runs.

- :mod:`wfjax.program.core`: the program, its one run (:func:`~wfjax.program.core.run_one`),
  what to save and how to differentiate;
- :mod:`wfjax.program.laws`: the contact laws, roughness and support realisations prepared on
  the host;
- :mod:`wfjax.program.grid`: the runs of a grid planned, chunked and sharded over the devices.
"""
