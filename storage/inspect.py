"""``format_inspection``: a human summary of a run's committed buffer (``gpl-dist inspect``)."""

from __future__ import annotations

import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from storage.fs import Location, resolve
from storage.layout import DATA, MANIFESTS, STAGING
from storage.manifest import committed_rounds, load_manifest
from storage.reader import BufferReader, read_verified


def _mib(n: int) -> str:
    return f"{n / 2**20:.2f} MiB"


def format_inspection(root: "str | os.PathLike[str] | Location", show_tasks: bool = False) -> str:
    """A human summary of the committed buffer at ``root``: schemas, rounds, attempts, disk use."""
    loc = resolve(root)
    reader = BufferReader(loc)
    rounds = committed_rounds(loc)
    manifests = [load_manifest(loc, r) for r in rounds]
    lines = [f"run root: {loc.url}"]
    if not manifests:
        lines.append("committed rounds: none")
        return "\n".join(lines)
    m0 = manifests[-1]
    lines.append(f"run id: {m0.run_id}   observation: shape {m0.obs_shape} dtype {m0.obs_dtype}")
    # schemas, from the newest committed shard's own files
    shard = next((s for m in reversed(manifests) for s in m.shards), None)
    if shard is not None:
        for role in ("attempts", "tuples"):
            (f,) = shard.files_of(role)
            schema = pq.read_schema(pa.BufferReader(read_verified(loc, f))).remove_metadata()
            lines.append(f"\n{role} schema ({f.path}):")
            lines.extend("  " + line for line in str(schema).splitlines())
    lines.append(f"\ncommitted rounds: {len(rounds)} ({rounds[0]}..{rounds[-1]})")
    lines.append(f"{'round':>6} {'shards':>7} {'attempts':>9} {'tuples':>10} {'bytes':>12}  created")
    for m in manifests:
        lines.append(f"{m.round_index:>6} {len(m.shards):>7} {m.num_attempts:>9} {m.num_tuples:>10} {m.nbytes:>12}  {m.created}")
    total_t = sum(m.num_tuples for m in manifests)
    total_a = sum(m.num_attempts for m in manifests)
    total_b = sum(m.nbytes for m in manifests)
    lines.append(f"{'total':>6} {sum(len(m.shards) for m in manifests):>7} {total_a:>9} {total_t:>10} {total_b:>12}")

    att = reader.read_table("attempts", rounds, ["task_id", "attempt_index", "completion", "success", "length"])
    k = att.column("attempt_index").to_numpy()
    comp = att.column("completion").to_numpy()
    succ = att.column("success").to_numpy(zero_copy_only=False).astype(bool)
    lines.append("\nby attempt index:")
    lines.append(f"{'k':>4} {'attempts':>9} {'mean_completion':>16} {'success_rate':>13}")
    for kk in np.unique(k):
        sel = k == kk
        lines.append(f"{int(kk):>4} {int(sel.sum()):>9} {comp[sel].mean():>16.4f} {succ[sel].mean():>13.4f}")

    committed_bytes = total_b
    all_bytes = loc.du([DATA, MANIFESTS, STAGING])
    lines.append(
        f"\ndisk: committed {_mib(committed_bytes)} ({committed_bytes / max(total_t, 1):.1f} bytes/tuple), "
        f"whole run directory {_mib(all_bytes)}"
    )
    if show_tasks:
        tasks = att.column("task_id").to_numpy()
        lines.append("\nby task:")
        lines.append(f"{'task':>6} {'attempts':>9} {'best_completion':>16} {'success':>8}")
        order = np.argsort(tasks, kind="stable")
        uniq, starts = np.unique(tasks[order], return_index=True)
        for t, grp in zip(uniq, np.split(order, starts[1:])):
            lines.append(f"{int(t):>6} {len(grp):>9} {comp[grp].max():>16.4f} {str(bool(succ[grp].any())):>8}")
    return "\n".join(lines)
