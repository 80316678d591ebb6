import jax
import pytest

# The references and closed forms are compared in float64; float32 is tested explicitly.
jax.config.update("jax_enable_x64", True)


@pytest.fixture
def table1():
    import jaximpact

    return jaximpact.table1_scene()
