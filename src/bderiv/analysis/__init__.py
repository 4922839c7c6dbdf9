"""Analysis over a model: its flow map's B-derivative along a trajectory
(:mod:`~bderiv.analysis.flowmap`, assembled group by group in ``assembly``), return maps
(:mod:`~bderiv.analysis.returnmap`), periodic orbits (:mod:`~bderiv.analysis.orbit`) and
their stability (:mod:`~bderiv.analysis.stability`,
:mod:`~bderiv.analysis.stability_map`), checks against finite differences
(:mod:`~bderiv.analysis.checks`) and of a model's Jacobians
(:mod:`~bderiv.analysis.jacobians`), and :class:`~bderiv.analysis.system.HybridSystem`,
the user's model with these analyses as its methods."""
