"""The Python examples of README.md (its fenced ``python`` blocks) run as written.

Running them compiles the simulator, a gradient and a fit: about 10 s with a warm compilation
cache and 40-50 s from a cold one on 2 cores, so the run is marked slow; the default run checks
that each block parses and that every ``ji.``/``fitting.`` name it uses exists."""

import ast
import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).parents[1]


def readme_blocks() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL)


def test_readme_has_python_examples():
    assert readme_blocks()


@pytest.mark.parametrize("index", range(len(readme_blocks())))
def test_readme_example_names_exist(index):
    import fitting
    import jaximpact

    tree = ast.parse(readme_blocks()[index])
    modules = {"ji": jaximpact, "jaximpact": jaximpact, "fitting": fitting}
    used = {
        (node.value.id, node.attr)
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Name)
        and node.value.id in modules
    }
    missing = [f"{m}.{a}" for m, a in sorted(used) if not hasattr(modules[m], a)]
    assert not missing, missing


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(readme_blocks())))
def test_readme_example_runs(index, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # anything an example writes lands here
    namespace = {"__name__": "__readme__"}
    exec(compile(readme_blocks()[index], f"README.md python block {index}", "exec"), namespace)
    if "res" in namespace:
        assert (namespace["res"].status_names == "rebound").all()
    if "fit" in namespace:
        assert namespace["fit"].status == "converged"
        assert namespace["fit"].values["friction"] == pytest.approx(0.0957, abs=2e-3)
