"""The ground-support page (``sil gsu``): a local web application beside an engine on a bench,
attached to the ECU through its standard interfaces only: the CAN contract's frames for live
values (:mod:`~sil.console.gsu.live`) and XCP for parameters, commands and the logbook
(:mod:`~sil.console.gsu.xcp_link`), so it serves every ECU implementation alike."""
