"""Bus fault injection: per message ID and time window, seeded (see :mod:`sil.busfault.spec`).

- :mod:`~sil.busfault.spec`: what a fault is (kind, IDs, window, rates) and what the ECU must do
  about it (detect within N ticks, reach a fallback mode, recover);
- :mod:`~sil.busfault.injector`: the per-frame decisions, deterministic for a seed;
- :mod:`~sil.busfault.inproc`: the injector between the nodes of an in-process run;
- :mod:`~sil.busfault.bridge`: the injector as a bridge between two python-can buses (real time).
"""
