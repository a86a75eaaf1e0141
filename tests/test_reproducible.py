"""The test session runs torch on its CPU-independent code paths (tests/conftest.py), so that
the in-session trainings, and every threshold tuned on them, are the same on any x86-64 CI
machine with AVX2."""
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: one quick training of a tip-contact model and of the LSTM (oneDNN's kernels) on the committed
#: test sweep; prints the sha256 of each model's weights
TRAIN = """
import hashlib
import torch
from deapull.surrogate.data import load_sweep
from deapull.surrogate.train import TrainConfig, train
torch.set_num_threads(1)
sweep = load_sweep("tests/data/sweep", ["C1", "C2"])
for kind, extra in (("f-coulomb", dict(epochs=20)), ("lstm", dict(epochs=3, hidden=32, batch_size=64))):
    model = train(TrainConfig(kind=kind, **extra), [sweep["C1"]], sweep["C2"]).model
    h = hashlib.sha256()
    for _, v in sorted(model.state_dict().items()):
        h.update(v.detach().numpy().tobytes())
    print(kind, h.hexdigest())
"""


def test_torch_runs_its_default_kernels_mkl_its_reproducible_branch_and_onednn_avx2():
    import torch
    assert torch.backends.cpu.get_cpu_capability() == "DEFAULT"
    assert os.environ["MKL_CBWR"] == "COMPATIBLE"
    assert os.environ["ONEDNN_MAX_CPU_ISA"] == "AVX2"


def test_a_training_is_the_same_whichever_instructions_mkl_may_use():
    """The session's pins make a training independent of the BLAS kernels the CPU offers: with
    MKL held to SSE4.2 (what an older CPU would run) the weights are bit for bit those of the
    MKL this machine picks. Broken once (MKL_CBWR left out of both runs): the hashes differed."""
    def weights(**extra):
        env = dict(os.environ, **extra)
        run = subprocess.run([sys.executable, "-c", TRAIN], capture_output=True, text=True, env=env, cwd=REPO,
                             timeout=600)
        assert run.returncode == 0, run.stderr[-2000:]
        return run.stdout.split()
    assert weights() == weights(MKL_ENABLE_INSTRUCTIONS="SSE4_2")
