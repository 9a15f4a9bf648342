"""``head360 bench synth``: speed of the corpus renderer and of writing a corpus subset.

Target (issue: SynHead-P): one 256x256 view in at most 50 ms on a 2-core CPU.
"""

from __future__ import annotations

import tempfile
import time
from typing import Any

import numpy as np

__all__ = ["bench_synth"]


def _render_timings(size: int, repeats: int) -> list[dict[str, Any]]:
    from head360cli.geometry.cameras import RIG_FOV_DEG, intrinsics_from_fov, rig72
    from head360cli.synth.scene import make_head, render_head

    head = make_head(3)
    c2w, _, _ = rig72()
    k = intrinsics_from_fov(RIG_FOV_DEG, size, size)
    w = np.zeros(52)
    rows = []
    for samples in (1, 2, 4):
        for batch in (1, 8):
            render_head(head, w, c2w[:batch], k, size, samples=samples)  # warm up
            t0 = time.perf_counter()
            n = 0
            for start in range(0, repeats, batch):
                render_head(head, w, c2w[start:start + batch], k, size, samples=samples)
                n += batch
            ms = 1000 * (time.perf_counter() - t0) / n
            rows.append({"size": size, "aa_samples": samples, "batch": batch,
                         "ms_per_view": round(ms, 1), "meets_50ms": ms <= 50.0})
    return rows


def bench_synth(identities: int = 100, size: int = 256, repeats: int = 24,
                out_dir: str | None = None) -> tuple[dict[str, Any], str]:
    """Measure render speed and the time to write ``identities`` identities
    (1 expression x 4 views each, with and without hair).

    Returns:
        ``(result, markdown)``.
    """
    from head360cli.bench.report import machine, markdown_table
    from head360cli.synth.corpus import CorpusConfig, write_corpus

    rows = _render_timings(size, repeats)
    cfg = CorpusConfig(identities=identities, expressions=1, views=4, size=size, seed=0)
    with tempfile.TemporaryDirectory(dir=out_dir) as tmp:
        t0 = time.perf_counter()
        summary = write_corpus(cfg, tmp)
        corpus_s = time.perf_counter() - t0
    subset = {"identities": identities, "expressions": 1, "views": 4, "size": size,
              "renders": 2 * summary["views"], "seconds": round(corpus_s, 1),
              "seconds_per_identity": round(corpus_s / identities, 3)}
    result = {"machine": machine(), "render": rows, "corpus_subset": subset}
    md = "### Corpus renderer (256x256 views)\n\n" + markdown_table(
        rows, ["size", "aa_samples", "batch", "ms_per_view", "meets_50ms"])
    md += ("\n\n### Corpus subset\n\n"
           f"{identities} identities x 1 expression x 4 views, with and without hair "
           f"({subset['renders']} renders, PNGs, masks, index): {subset['seconds']} s, "
           f"{subset['seconds_per_identity']} s per identity.")
    return result, md
