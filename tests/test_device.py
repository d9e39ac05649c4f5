"""Device selection: one-line errors instead of torch tracebacks."""

import pytest

torch = pytest.importorskip("torch", reason="the learning extra (torch) is not installed")

from spotlights.errors import ParameterError  # noqa: E402
from spotlights.learning.device import resolve_device  # noqa: E402


def test_default_and_cpu():
    assert resolve_device("cpu").type == "cpu"
    assert resolve_device(None).type == ("cuda" if torch.cuda.is_available() else "cpu")


@pytest.mark.parametrize("name", ["nosuch", "cuda:99"])
def test_unknown_or_missing_devices_rejected(name):
    with pytest.raises(ParameterError):
        resolve_device(name)


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
def test_cuda_without_cuda_rejected():
    with pytest.raises(ParameterError, match="CUDA is not available"):
        resolve_device("cuda")
