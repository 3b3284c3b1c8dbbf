import os

import pytest
import torch

os.environ.setdefault("COLUMNS", "160")
torch.set_num_threads(1)


@pytest.fixture()
def registry(tmp_path, monkeypatch):
    reg = tmp_path / "registry"
    monkeypatch.setenv("MIKT_REGISTRY", str(reg))
    return reg
