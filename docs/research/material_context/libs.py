"""Cache the run library (set_endmembers over sets 1..8 pooled, as exp_edge_candidates.py) per scene."""

import pickle
import sys
import time
import warnings
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "run_library"))
warnings.simplefilter("ignore")
from refine import pooled_inputs  # noqa: E402
from runlib import simulate  # noqa: E402

from spectralize.nodes.reconstruction.estimators.endmember_mixture import set_endmembers  # noqa: E402

CACHE = HERE.parent / "run_library" / "cache"


def run_library(name: str):
    path = CACHE / f"{name}_48_runlib_1-8.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    sets = [simulate(name, 48, k) for k in range(1, 9)]
    lib = set_endmembers(pooled_inputs(sets))
    path.write_bytes(pickle.dumps(lib))
    return lib


if __name__ == "__main__":
    for n in sys.argv[1].split(","):
        t = time.process_time()
        run_library(n)
        print(n, f"{time.process_time() - t:.1f} CPU-s", flush=True)
