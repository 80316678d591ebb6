"""The engine: ``simulate`` and what it needs to integrate the model (step loop, Tsit5 tableau,
event locator, solver and tolerance choice, devices, derivatives, the result type)."""
