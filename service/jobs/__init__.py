"""Jobs and their cells: one impostor per view cell of a scene, or a placement job's impostors.

- :mod:`.schema`: the request (:class:`~farfield.service.jobs.schema.JobSpec`, a grid, the cell limit);
- :mod:`.admission`: a job from a request in O(cells), or a refusal (a lower bound of its cells' cost,
  the tenant's cells in flight capped; a placement job admitted by its algorithm, :mod:`farfield.service.placement`);
- :mod:`.admitting`: a job ``admitting``: every cell's full check on a worker before any is baked;
- :mod:`.cells`: the cell state machine (claim, attempts, end; a job's end), the API's cancel and retry;
- :mod:`.runner`: one cell on a worker, start to end (what the bake task runs), its failures sorted
  (:mod:`farfield.service.failures`);
- :mod:`.records`: the job and cell records the API shows, and the queries behind them;
- :mod:`.index`: the impostor database index of a job, and the lookup from a viewpoint to its cells.

Placement jobs (:mod:`farfield.service.placement`) build on nothing here; this package asks the placement
registry for a placement job's part (its admission, the end of its rounds, its cells' kind, its
index and lookup), so the two import each other in one direction only.
"""
