"""The event logic at a stop of either integrator: location and windows (``locate``),
grouping, switching and resets (``crossings``), excursions inside a step (``excursions``,
the sampled peaks of the event values in ``peaks``) and a group at the final time
(``finaltime``)."""
