"""Training a latent SVBRDF decoder on the procedural materials (``bayes-brdf train-decoder``)."""
from .vae import Encoder, vae_loss
from .train import TrainConfig, train_decoder

__all__ = ["Encoder", "vae_loss", "TrainConfig", "train_decoder"]
