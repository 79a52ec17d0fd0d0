"""The report of a protocol run: summaries of its rows, Markdown tables and the results files.

Two kinds of rows share the writer: benchmark rows (`summarize` / `format_table`: error columns
with baselines side by side, NMI, correct K) and end-to-end rows (`summarize_rows` / `format_rows`:
any numeric column, NaN for clips that could not be scored). `write_results` writes results.json
(config, summary, rows), results.csv (rows) and results.md (config and table) atomically.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mosegpipe.evaluation.metrics import correct_k_rate
from mosegpipe.io.read import write_csv, write_text


def _mean_median(vals: np.ndarray) -> dict[str, float]:
    """{"mean", "median"} of a 1-D array (NaN for an empty one)."""
    return {
        "mean": float(vals.mean()) if vals.size else float("nan"),
        "median": float(np.median(vals)) if vals.size else float("nan"),
    }


def _markdown(heads: list[str], body: list[list[str]], notes: str) -> str:
    """A Markdown table (header, separator, body rows) followed by a blank line and `notes`."""
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    lines += ["| " + " | ".join(cells) + " |" for cells in body]
    return "\n".join(lines) + "\n\n" + notes + "\n"


def summarize(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Mean / median of every error column, correct-K rate and total time over the rows."""
    if not rows:
        return {}
    out: dict[str, Any] = {"num_clips": len(rows)}
    error_cols = [c for c in rows[0] if c.startswith("error") or "@" in c]
    for col in error_cols:
        out[col] = _mean_median(np.array([r[col] for r in rows if col in r], dtype=np.float64))
    if "k_pred" in rows[0]:
        out["correct_k"] = correct_k_rate([r["k_pred"] for r in rows], [r["k_true"] for r in rows])
        out["nmi"] = float(np.mean([r["nmi"] for r in rows]))
        out["seconds_total"] = float(sum(r["seconds"] for r in rows))
    return out


def format_table(rows: Sequence[dict[str, Any]], summary: dict[str, Any]) -> str:
    """A Markdown table: one row per clip (errors in %), then mean and median rows."""
    if not rows:
        return "(no rows)\n"
    cols = list(rows[0].keys())
    pct = {c for c in cols if c.startswith("error") or "@" in c}

    def fmt(col: str, val: Any) -> str:
        if col in pct:
            return f"{100 * val:.2f}"
        if col == "seconds":
            return f"{1000 * val:.1f}ms"
        if isinstance(val, float):
            return f"{val:.3f}"
        return str(val)

    body = [[fmt(c, r.get(c, "")) for c in cols] for r in rows]
    for stat in ("mean", "median"):
        body.append([f"**{stat}**"] + [f"{100 * summary[c][stat]:.2f}" if c in pct else "" for c in cols[1:]])
    extra = []
    if "correct_k" in summary:
        extra.append(
            f"correct K: {100 * summary['correct_k']:.2f} % · mean NMI {summary['nmi']:.3f} · "
            f"embedding + automatic K for all {summary['num_clips']} clips: {summary['seconds_total']:.3f} s"
        )
    return _markdown(cols, body, "\n".join(extra))


def write_results(
    out_dir: Path, rows: list[dict[str, Any]], summary: dict[str, Any], config: dict[str, Any], table: str | None = None
) -> str:
    """Writes results.json (config, summary, rows), results.csv (rows) and results.md (config + table)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    table = table if table is not None else format_table(rows, summary)
    # default=float: numpy scalars in rows and summaries are written as JSON numbers.
    write_text(
        out_dir / "results.json",
        json.dumps({"config": config, "summary": summary, "rows": rows}, indent=2, default=float),
    )
    write_csv(out_dir / "results.csv", rows)
    write_text(
        out_dir / "results.md", f"# {config.get('protocol')}\n\n```json\n{json.dumps(config, indent=2)}\n```\n\n{table}"
    )
    return table


_TEXT_COLUMNS = ("name", "seed", "camera")


def _numeric_columns(rows: Sequence[dict[str, Any]]) -> list[str]:
    cols = []
    for c in rows[0]:
        if c in _TEXT_COLUMNS:
            continue
        if all(isinstance(r.get(c), (int, float, np.integer, np.floating)) for r in rows):
            cols.append(c)
    return cols


def summarize_rows(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Mean and median of every numeric column over the scored rows, correct-K rate, total time.

    Args:
        rows: rows from one of the protocols.

    Returns:
        {"num_rows", "num_unscored" (rows whose error / track_error is NaN), "<column>": {"mean",
        "median"} for each numeric column over the scored rows (NaN when none is), "correct_k"
        (fraction of scored rows with k_pred == k_true), "correct_k_5" (the same against k_true_5, where the
        rows have it), "seconds_total" (all rows)}; {} for no rows.
    """
    if not rows:
        return {}
    err_col = "error" if "error" in rows[0] else "track_error" if "track_error" in rows[0] else None
    scored = [r for r in rows if err_col is None or np.isfinite(r[err_col])]
    out: dict[str, Any] = {"num_rows": len(rows), "num_unscored": len(rows) - len(scored)}
    for c in _numeric_columns(rows):
        vals = np.array([r[c] for r in scored], dtype=np.float64)
        out[c] = _mean_median(vals[np.isfinite(vals)])
    if scored and "k_true" in rows[0] and "k_pred" in rows[0]:
        out["correct_k"] = float(np.mean([r["k_pred"] == r["k_true"] for r in scored]))
    if scored and "k_true_5" in rows[0] and "k_pred" in rows[0]:  # kt3d-video: the motions enough tracks carry
        out["correct_k_5"] = float(np.mean([r["k_pred"] == r["k_true_5"] for r in scored]))
    if "seconds" in rows[0]:
        out["seconds_total"] = float(sum(r["seconds"] for r in rows))
    return out


def _is_error(col: str) -> bool:
    """Error columns: SubspaceNet's ("error", "error_true_k", ...) and the baselines' ("ssc@K", ...)."""
    return "error" in col or col.endswith(("@K", "@auto"))


def _fmt(col: str, val: Any, digits: int = 1) -> str:
    if isinstance(val, (float, np.floating)) and not np.isfinite(val):
        return "–"
    if _is_error(col):
        return f"{100 * val:.2f}"
    if col == "seconds":
        return f"{1000 * val:.0f}"
    if col.startswith(("J", "F", "j_object")):
        return f"{val:.3f}"
    if isinstance(val, (float, np.floating)):
        return f"{val:.{digits}f}"
    return str(val)


def format_rows(rows: Sequence[dict[str, Any]]) -> str:
    """A Markdown table of protocol rows with mean and median rows underneath.

    Errors are shown in percent, J and F as fractions, seconds in milliseconds; NaN as "–".

    Args:
        rows: rows from one of the protocols.

    Returns:
        The table and a line with the correct-K rate and total time, newline-terminated.
    """
    if not rows:
        return "(no rows)\n"
    summary = summarize_rows(rows)
    cols = list(rows[0])
    heads = [f"{c} (%)" if _is_error(c) else "ms" if c == "seconds" else c for c in cols]
    body = [[_fmt(c, r.get(c, "")) for c in cols] for r in rows]
    for stat in ("mean", "median"):
        body.append(
            [f"**{stat}**"]
            + [_fmt(c, summary[c][stat]) if c in summary and isinstance(summary[c], dict) else "" for c in cols[1:]]
        )
    notes = [f"{summary['num_rows']} clips"]
    if summary["num_unscored"]:
        notes.append(f"{summary['num_unscored']} not scored (too few tracks or matches)")
    if "correct_k" in summary:
        notes.append(f"correct K {100 * summary['correct_k']:.1f} %")
    if "correct_k_5" in summary:
        notes.append(f"against the motions of 5 scored tracks or more {100 * summary['correct_k_5']:.1f} %")
    if "seconds_total" in summary:
        notes.append(f"total {summary['seconds_total']:.2f} s")
    return _markdown(heads, body, " · ".join(notes))
