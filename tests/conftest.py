import os
from pathlib import Path

import jax
import pytest

# The references and closed forms are compared in float64; float32 is tested explicitly.
jax.config.update("jax_enable_x64", True)


@pytest.fixture
def table1():
    import jaximpact

    return jaximpact.table1_scene()


# One persistent compilation cache for the test run, as a user's processes share one (the
# default for users, there in the user cache directory): both workers, the commands run in
# subprocesses and the notebooks' kernels load a program another one compiled, and a later run
# (CI's slow step after its default run, an edited module's rerun) loads what an earlier one
# compiled (the key is the lowered program, so an edit compiles afresh). In .pytest_cache,
# which git ignores; JAXIMPACT_TEST_CACHE_DIR moves it, or turns it "off" (every process then
# compiles its own). Tests of the cache itself pass their own JAXIMPACT_CACHE_DIR.
_cache = os.environ.get("JAXIMPACT_TEST_CACHE_DIR", "").strip() or str(
    Path(__file__).resolve().parent.parent / ".pytest_cache" / "jax-compilation-cache"
)
os.environ["JAXIMPACT_CACHE_DIR"] = _cache


# Files whose selected tests take the longest, handed to the xdist workers first: with one file
# per work unit (--dist loadfile) a long file handed out last keeps one worker busy after the
# other has finished. Measured in CI's slow step (2026-11-28, 2 cores): test_wall_law_aligned
# about 280 s (its two-decade command 236 s), the notebooks 265 s, the leave-one-out tests
# 210 s, the wall law's radius and grid tests 150 s, the posterior's commands 130 s; that step
# took 1,166 s with xdist's default order (files with more tests first), which gave the
# aligned file out near the end.
LONGEST_FIRST = (
    "test_wall_law_aligned.py",
    "test_notebooks.py",
    "test_loo.py",
    "test_wall_law.py",
    "test_posterior.py",
)


@pytest.hookimpl(trylast=True)  # after -m has deselected
def pytest_collection_modifyitems(config, items):
    """The files of :data:`LONGEST_FIRST` first, then the others by their number of selected
    tests (xdist's own order, which --no-loadscope-reorder turns off); a file's tests keep
    their order."""
    from collections import Counter

    counts = Counter(item.path.name for item in items)

    def rank(item):
        name = item.path.name
        if name in LONGEST_FIRST:
            return (0, LONGEST_FIRST.index(name))
        return (1, -counts[name])

    items[:] = sorted(items, key=rank)
