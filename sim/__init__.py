"""The simulated Panda: Pinocchio model, payloads, paths, the MuJoCo plant and the tandem
simulators that produce training samples. Import the submodules directly; this package does
not import them eagerly, so ``import sim.payload`` stays light."""
