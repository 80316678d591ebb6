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
