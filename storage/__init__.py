"""gpl-dist's labelled-state buffer: sharded Parquet tables + Zarr observations + round manifests.

See ``docs/buffer.md`` for the layout, the schemas and the commit protocol.
"""

from storage.cleanup import clean_leftovers
from storage.commit import commit_round, recover_pending
from storage.errors import BufferIntegrityError
from storage.inspect import format_inspection
from storage.manifest import RoundManifest, ShardFile, ShardRecord, committed_rounds, load_manifest
from storage.reader import BufferReader, TrainingView
from storage.writer import ShardWriter

__all__ = [
    "BufferIntegrityError",
    "BufferReader",
    "RoundManifest",
    "ShardFile",
    "ShardRecord",
    "ShardWriter",
    "TrainingView",
    "clean_leftovers",
    "commit_round",
    "committed_rounds",
    "format_inspection",
    "load_manifest",
    "recover_pending",
]
