"""The benches: one module per bench, each with ``run(quick: bool) -> dict`` returning its figures
(speed and memory, with the targets it checks), and this registry of them for ``sil bench``;
:mod:`sil.bench.suite` runs them all and writes docs/benchmarks.md, :mod:`sil.bench.common`
holds what they share."""

# target -> module with `run(quick: bool) -> dict` returning the figures
TARGETS = {
    "codec": "protocol.bench",
    "plant": "plant.bench",
    "ecu": "ecu.bench",
    "replay": "sil.bench.replay",
    "sil": "sil.bench.speed",
    "service": "sil.bench.service",
    "port": "sil.bench.port",
    "realtime": "sil.bench.realtime",
    "pil": "sil.bench.pil",
    "starts": "sil.bench.starts",
    "control": "sil.bench.control",
    "fleet": "sil.bench.fleet",
    "campaign": "sil.bench.campaign",
    "gsu": "sil.bench.gsu",
    "tests": "sil.bench.tests",
}
