"""``--precision auto``: bf16 with torch where the CPU multiplies bfloat16 natively (avx512_bf16 or AMX flags,
simulated here for both kinds of CPU), fp32 elsewhere and with onnxruntime; the summary says which ran."""

from __future__ import annotations

import pytest

from spotlights.learning import cpu
from spotlights.learning import runtime as rt

CPUINFO_AMD = """processor\t: 0
vendor_id\t: AuthenticAMD
model name\t: AMD EPYC 9R14 96-Core Processor
flags\t\t: fpu sse2 avx2 avx512f avx512bw avx512_bf16 avx512_vnni
"""
CPUINFO_OLD = """processor\t: 0
model name\t: Intel(R) Xeon(R) CPU E5-2686 v4 @ 2.30GHz
flags\t\t: fpu sse2 avx avx2 fma
"""
CPUINFO_AMX = """processor\t: 0
model name\t: Intel(R) Xeon(R) Platinum 8488C
flags\t\t: fpu avx2 avx512f amx_bf16 amx_tile amx_int8
"""


@pytest.mark.parametrize(
    "text, name, bf16, amx",
    [
        (CPUINFO_AMD, "AMD EPYC 9R14 96-Core Processor", True, False),
        (CPUINFO_OLD, "Intel(R) Xeon(R) CPU E5-2686 v4 @ 2.30GHz", False, False),
        (CPUINFO_AMX, "Intel(R) Xeon(R) Platinum 8488C", True, True),
    ],
)
def test_cpu_flags_name_and_bf16_from_cpuinfo(tmp_path, text, name, bf16, amx):
    path = tmp_path / "cpuinfo"
    path.write_text(text)
    flags = cpu.cpu_flags(path)
    assert cpu.cpu_model(path) == name and cpu.has_bf16(flags) is bf16
    d = cpu.cpu_description(flags, model=name)
    assert d["amx"] is amx and d["avx512_bf16"] is ("avx512_bf16" in text) and d["model"] == name
    assert cpu.auto_precision("torch", "cpu", flags) == ("bf16" if bf16 else "fp32")
    assert cpu.auto_precision("onnx", "cpu", flags) == "fp32"  # the exports run float32
    assert cpu.auto_precision("torch", "cuda", flags) == "auto"  # torch chooses on a GPU


def test_no_cpuinfo_means_no_flags_and_fp32(tmp_path):
    assert cpu.cpu_flags(tmp_path / "absent") == frozenset() and cpu.cpu_model(tmp_path / "absent") == "unknown"
    assert cpu.auto_precision("torch", "cpu", frozenset()) == "fp32"


@pytest.mark.parametrize("flags, expect", [({"avx2", "avx512_bf16"}, "bf16"), ({"avx2"}, "fp32")])
@pytest.mark.timeout(120)
def test_load_completer_auto_precision_follows_the_simulated_cpu(monkeypatch, flags, expect):
    pytest.importorskip("torch")
    monkeypatch.setattr(cpu, "cpu_flags", lambda path=cpu.CPUINFO: frozenset(flags))
    monkeypatch.setattr(rt, "cuda_present", lambda: False)
    c = rt.load_completer("paper", device="cpu")  # no export shipped: torch
    assert (c.runtime, c.precision) == ("torch", expect) and rt.runs_with(c) == f"torch {expect}"
    assert rt.load_completer("paper", device="cpu", precision="fp32").precision == "fp32"
    onx = rt.load_completer("default", device="cpu")  # the shipped export: onnxruntime, float32 on any CPU
    assert (onx.runtime, onx.precision) == ("onnx", "fp32") and rt.runs_with(onx) == "onnxruntime fp32"
    assert rt.load_completer("default", device="cpu", precision="bf16").runtime == "torch"  # bf16 asked: torch
