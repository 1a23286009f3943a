"""The optional torch dependency: one-line messages when CUDA is asked for and absent."""
from __future__ import annotations

import pytest

from pencilcal.toolkit.pencil import torch_backend as tb

needs_torch = pytest.mark.skipif(not tb.torch_available(), reason='torch/kornia not installed (pip install -e ".[torch]")')


@needs_torch
def test_cuda_missing_is_one_line():
    import torch

    if torch.cuda.is_available():
        pytest.skip("a GPU is present")
    with pytest.raises(tb.TorchUnavailableError) as e:
        tb.resolve_device("cuda")
    assert "\n" not in str(e.value) and "--device cpu" in str(e.value)
