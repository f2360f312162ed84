"""shearer-fusion: longwall shearer positioning by SINS + aiding sources in a (federated) Kalman filter."""

__version__ = "0.1.0"
