"""The model: what an impact is (the scene and its input ranges) and the equations of motion
(force laws, dynamics, Hertz units). No solver here: the engine integrates these equations."""
