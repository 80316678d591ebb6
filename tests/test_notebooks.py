"""The research notebooks run top to bottom (small sizes) and are stored without errors."""

import json
import os
import re
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parent.parent / "notebooks").glob("*.ipynb"))
NAMES = [p.name for p in NOTEBOOKS]


def test_notebooks_present():
    assert NAMES == [
        "01_reproduce_brach_dunn_cheng_1999.ipynb",
        "02_identify_parameters.ipynb",
        "03_batched_exploration.ipynb",
        "04_accuracy_and_cost.ipynb",
        "05_uncertainty_and_design.ipynb",
        "06_wall_law.ipynb",
    ]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=NAMES)
def test_stored_notebook_is_clean(path):
    nb = json.loads(path.read_text())
    cells = nb["cells"]
    assert cells[0]["cell_type"] == "markdown" and cells[-1]["cell_type"] == "markdown"
    code = [c for c in cells if c["cell_type"] == "code"]
    first = "".join(code[0]["source"])
    assert 'SMALL = os.environ.get("JAXIMPACT_NOTEBOOK_SMALL") == "1"' in first
    assert 'jax.config.update("jax_enable_x64", True)' in first
    for cell in code:
        source = "".join(cell["source"])
        assert "jaximpact._" not in source and "../shared" not in source
        assert cell.get("execution_count") is not None, "stored notebooks are executed"
        for out in cell.get("outputs", []):
            assert out["output_type"] != "error", f"{path.name}: stored error output"
            assert out.get("name") != "stderr", f"{path.name}: stored stderr output"
            text = json.dumps(out.get("text", "")) + json.dumps(
                out.get("data", {}).get("text/plain", "")
            )
            assert not re.search(r"/(work|home|tmp|Users)/", text), f"{path.name}: local path"
    assert path.stat().st_size < 1_500_000


@pytest.fixture(scope="module")
def shared_cache():
    """The test run's compilation cache (tests/conftest.py) for the notebooks' kernels too,
    as a user's sessions share one: a program compiled before (the Table 1 scene's, a fit's)
    loads in a notebook, and one notebook's in the next."""
    return os.environ["JAXIMPACT_CACHE_DIR"]


@pytest.mark.slow  # about a minute each: CI's second step
@pytest.mark.parametrize("path", NOTEBOOKS, ids=NAMES)
def test_notebook_executes(path, monkeypatch, shared_cache):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    monkeypatch.setenv("JAXIMPACT_NOTEBOOK_SMALL", "1")
    monkeypatch.setenv("JAXIMPACT_CACHE_DIR", str(shared_cache))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        nb,
        timeout=600,
        kernel_name="python3",
        resources={"metadata": {"path": str(path.parent)}},
    )
    client.execute()  # raises CellExecutionError on any error
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            assert out["output_type"] != "error"
    assert os.environ["JAXIMPACT_NOTEBOOK_SMALL"] == "1"
