"""The world and its simulator (world.md): what a scenario holds, how robots move,
perceive and collide, encirclement, the scripted evader, rewards and metrics, the
batched `World` and the one-world `Simulator`.

NumPy only: nothing here imports onnxruntime, mcap or torch.
"""
