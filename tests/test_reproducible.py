"""The test session runs torch on its CPU-independent code paths (tests/conftest.py), so that
the in-session trainings, and every threshold tuned on them, are the same on any x86-64 CI
machine."""
import os


def test_torch_runs_its_default_kernels_mkl_its_reproducible_branch_and_onednn_avx2():
    import torch
    assert torch.backends.cpu.get_cpu_capability() == "DEFAULT"
    assert os.environ["MKL_CBWR"] == "COMPATIBLE"
    assert os.environ["ONEDNN_MAX_CPU_ISA"] == "AVX2"
