"""Figures and pictures of runs: metrics, plots and model identification (below the runs, which
use them; sil.verify, the source document's results, runs scenarios and stands above)."""
