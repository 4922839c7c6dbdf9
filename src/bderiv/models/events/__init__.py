"""The event logic at a stop of either integrator: location and windows (``locate``),
grouping, switching and resets (``crossings``), excursions inside a step (``excursions``)
and a group at the final time (``finaltime``)."""
