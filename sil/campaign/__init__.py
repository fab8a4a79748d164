"""Campaigns: many in-process runs of one base scenario across engine variation, controllers,
bus faults and seeds, on a local process pool or a Dask cluster (``sil campaign``).

- :mod:`~sil.campaign.spec`: the campaign file and the cases it expands to;
- :mod:`~sil.campaign.case`: one case, in process, with a lean probe instead of the recorder;
- :mod:`~sil.campaign.invariants`: what must hold in every run;
- :mod:`~sil.campaign.executors`: local pool or Dask, results streamed into one CSV, resumable;
- :mod:`~sil.campaign.report`: plots and a Markdown summary.
"""
