"""The photon Monte Carlo's parts: physics (:mod:`~xray_viz.montecarlo.physics`), geometry
(:mod:`~xray_viz.montecarlo.geometry`), sources (:mod:`~xray_viz.montecarlo.sources`) and tallies
(:mod:`~xray_viz.montecarlo.tallies`), meeting in one short loop
(:mod:`~xray_viz.montecarlo.loop`); random streams per batch (:mod:`~xray_viz.montecarlo.rng`);
``xray-viz dose`` (:mod:`~xray_viz.montecarlo.command`). The entry point is
:func:`xray_viz.transport` (:mod:`xray_viz.transport`).
"""
