"""Many takes at once: re-solve and re-export whole sessions, on this machine or on Ray.

    report = run_batch(["session/*.mcap"], "exports", formats=("gltf", "usd"), engine="local")

One take is one task (``task.run_take``: the same ``export_take`` / ``play_take`` as ``puppet
export`` and ``puppet play``, on the same rig: the take's own, or the one given, so outputs are
byte-identical). Each rig's precompute is built once by the driver and sent once to each worker
(``local``: a process pool; ``ray``: the object store). Modules: plan (takes, outputs, each
take's rig), manifest (what outputs were made from: ``--resume``), task (the worker's work), row
(one take's row: state, worker, times, retries, outputs, reason, log), local and ray_engine (the
engines), run (the driver and its report).
"""

from puppet.batch.cancel import BatchCancelled
from puppet.batch.errors import BatchError
from puppet.batch.plan import DEFAULT_FORMATS, FORMATS, SUFFIXES
from puppet.batch.row import STATES, TakeResult
from puppet.batch.run import ENGINES, BatchReport, run_batch

__all__ = ["BatchCancelled", "BatchError", "BatchReport", "DEFAULT_FORMATS", "ENGINES", "FORMATS",
           "STATES", "SUFFIXES", "TakeResult", "run_batch"]
