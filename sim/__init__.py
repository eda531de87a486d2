"""The simulated arm (its description, :mod:`sim.description`: the Panda, the FR3 or a URDF):
Pinocchio model, payloads, paths, the MuJoCo plant and the tandem
simulators that produce training samples. Import the submodules directly; this package does
not import them eagerly, so ``import sim.payload`` stays light."""
