"""Stage 7: match a measured skyline profile against a database of predicted skylines.

For every database position the best azimuth shift (the heading) minimises the sum of squared
differences over the query's observed bins after a least-squares fit of a nuisance model (a
constant; optionally the first azimuthal harmonic of a small pitch/roll). :mod:`.scores` holds
the maths (FFT cross-correlations and the slow direct reference), :mod:`.search` the streaming
search over a database's blocks that keeps the best candidates at least a suppression radius
apart, and :mod:`.memory` an in-memory store with the database's block interface.

World/body convention: ``world[az] = body[az - H]``, so query bin ``j`` (body) meets database bin
``j + s`` (world) and the heading is ``H = s * 360 / n``.
"""

from .memory import MISSING_RAW, MemoryStore, grid_index
from .scores import (DenseQuery, Query, brute_force_scores, decimate_query, dense_query,
                     harmonic_basis, observed_span_deg, prepare_query, score_dense,
                     score_profiles, tilt_determinable)
from .search import PRESETS, Candidate, MatchConfig, MatchResult, match_database

__all__ = ["MISSING_RAW", "PRESETS", "Candidate", "DenseQuery", "MatchConfig", "MatchResult",
           "MemoryStore", "Query", "brute_force_scores", "decimate_query", "dense_query",
           "grid_index", "harmonic_basis", "match_database", "observed_span_deg", "prepare_query",
           "score_dense", "score_profiles", "tilt_determinable"]
