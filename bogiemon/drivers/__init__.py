"""Sources: bytes and frames in, time-aligned blocks of (n, 3) samples in m/s^2 out."""
