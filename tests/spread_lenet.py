"""The spread behind the LeNet test's thresholds (tests/test_recognition.py): the test's training
(320 synthetic patches, half without a mass label, 2 members, 40 epochs) over many seeds, each
seed changing the training patches, the 100 test patches and the network's initialisation. Run
it under each kernel family, since the CPU's kernels change the trained network's last bits
much as a seed does:

    python tests/spread_lenet.py --seeds 40 > default.jsonl
    ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2 OPENBLAS_CORETYPE=Haswell python tests/spread_lenet.py --seeds 40 > avx2.jsonl
    ONEDNN_MAX_CPU_ISA=SSE41 ATEN_CPU_CAPABILITY=default python tests/spread_lenet.py --seeds 40 > sse.jsonl
    python tests/spread_lenet.py --summarise default.jsonl avx2.jsonl sse.jsonl

Not a test (pytest does not collect it): about 5 s a training on one core.
"""
import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

STATS = ("rho", "r2", "cover90", "sd_over_rms")


def one(seed: int) -> dict:
    from scipy.stats import spearmanr

    from galileo.recognition import lenet
    from test_recognition import synthetic_patches

    x, y = synthetic_patches(320, np.random.default_rng(seed))
    y[::2, 0] = np.nan
    xt, yt = synthetic_patches(100, np.random.default_rng(1 if seed == 0 else 1000 + seed))   # seed 0: the test's
    trained = lenet.train(x, y, seed=seed, members=2, epochs=40, progress=False)
    mean, sd = lenet.predict(trained.states, xt)
    out = {"seed": seed}
    for q, name in enumerate(("mass", "friction")):
        err = mean[:, q] - yt[:, q]
        out[name] = {"rho": float(spearmanr(mean[:, q], yt[:, q])[0]),
                     "r2": float(1 - np.mean(err ** 2) / np.var(yt[:, q])),
                     "cover90": float(np.mean(np.abs(err) < 1.645 * sd[:, q])),
                     "sd_over_rms": float(np.median(sd[:, q]) / math.sqrt(np.mean(err ** 2)))}
    return out


def summarise(files: list[str]) -> None:
    rows = [json.loads(line) for f in files for line in Path(f).read_text().splitlines() if line.startswith("{")]
    print(f"{len(rows)} trainings")
    for name in ("mass", "friction"):
        for k in STATS:
            v = np.array([r[name][k] for r in rows])
            print(f"{name:9s} {k:12s} min {v.min():.3f}  q05 {np.quantile(v, 0.05):.3f}  "
                  f"median {np.median(v):.3f}  max {v.max():.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40, help="seeds 0..N-1 (default 40)")
    ap.add_argument("--summarise", nargs="+", metavar="JSONL", help="summarise earlier runs instead")
    a = ap.parse_args()
    if a.summarise:
        summarise(a.summarise)
        return
    for seed in range(a.seeds):
        print(json.dumps(one(seed)), flush=True)


if __name__ == "__main__":
    main()
