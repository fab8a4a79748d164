"""The host side of the ECU service port: a client library (:mod:`sil.console.client`) and the
interactive terminal (:mod:`sil.console.interactive`), both used by ``sil console``."""
