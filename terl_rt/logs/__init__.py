"""Episode logs: the MCAP log format, its writer and reader, the Foxglove scene,
re-simulation of logged episodes and rendering them to images and animations."""
