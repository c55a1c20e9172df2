"""madp: multi-agent diffusion policies for decentralized coverage control."""

__version__ = "0.1.0"
