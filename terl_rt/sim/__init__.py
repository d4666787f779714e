"""The world and its simulator (world.md): what a scenario holds, how robots move,
perceive and collide, encirclement, the scripted evader, rewards and metrics, the
batched `World`, the one-world `Simulator` and `Rollout`, the loop that drives a
`World` and restarts its ended episodes.

NumPy only: nothing here imports onnxruntime, mcap or torch.
"""
