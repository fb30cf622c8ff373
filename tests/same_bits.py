"""Same bits across processes: run one piece of Python in several fresh interpreters at
once, each with its own PYTHONHASHSEED (and, where asked, its own torch thread count), and compare
the sha256 of what each printed. Hashes of arrays, HDF5 datasets and torch state_dicts, in a fixed
order, so "identical" means identical bits, not close."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def sha256_arrays(arrays: Mapping[str, object]) -> str:
    """sha256 over name, dtype, shape and bytes of every array, names in sorted order."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        array = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}|{array.dtype.str}|{array.shape}|".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def sha256_state_dict(state_dict: Mapping[str, object]) -> str:
    """sha256 of a torch state_dict's tensors (as sha256_arrays)."""
    return sha256_arrays({k: v.detach().cpu().numpy() for k, v in state_dict.items()})


def sha256_hdf5(path: str | os.PathLike) -> str:
    """sha256 of every dataset of an HDF5 file (not its attributes: a run's wall time is one)."""
    import h5py

    arrays = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, item: arrays.__setitem__(name, item[()]) if isinstance(item, h5py.Dataset) else None)
    return sha256_arrays(arrays)


def run_in_fresh_processes(
    script: str, argvs: Sequence[Sequence[str]], hash_seeds: Sequence[int] = (1, 2), env: Sequence[dict] | None = None
) -> list[str]:
    """Run `python -c script *argvs[k]` for each k, all at once (one core each on a 2-core box), each
    in a fresh interpreter with PYTHONHASHSEED hash_seeds[k] and the extra variables env[k]; returns
    each one's stdout (stripped). A failure shows its stderr."""
    processes = [
        subprocess.Popen(
            [sys.executable, "-c", script, *map(str, argv)],
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONHASHSEED": str(seed), **(env[k] if env else {})},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for k, (argv, seed) in enumerate(zip(argvs, hash_seeds, strict=True))
    ]
    outputs = []
    for process in processes:
        out, err = process.communicate(timeout=300)
        assert process.returncode == 0, err[-3000:]
        outputs.append(out.strip())
    return outputs
