import os

import jax
import pytest

# The references and closed forms are compared in float64; float32 is tested explicitly.
jax.config.update("jax_enable_x64", True)


@pytest.fixture
def table1():
    import jaximpact

    return jaximpact.table1_scene()


# The CLI turns JAX's persistent compilation cache on (user cache directory) unless told
# otherwise: tests that call it in-process must not write there nor change this process's JAX
# configuration. Tests of the cache pass their own JAXIMPACT_CACHE_DIR.
os.environ["JAXIMPACT_CACHE_DIR"] = "off"
