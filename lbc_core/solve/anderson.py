"""Anderson acceleration of a fixed-point map."""

import numpy as np


class Anderson:
    """Anderson acceleration (type II) of a fixed-point map, with the residual safeguard of Zhang et al. 2019."""

    def __init__(self, size, memory, dtype, check):
        self.memory = memory
        self.check = check  # called between passes over the history, which is several times the state's size
        self.dF = np.zeros((memory, size), dtype=dtype)  # residual differences
        self.dG = np.zeros((memory, size), dtype=dtype)  # map-value differences
        self.gram = np.zeros((memory, memory))
        self.count = 0
        self._residual, self._products = None, None  # the last pushed residual r and ΔF · r

    def reset(self):
        self.count = 0
        self._residual = None

    def push(self, value, residual, previous_value, previous_residual):
        slot = self.count % self.memory
        np.subtract(residual, previous_residual, out=self.dF[slot])
        self.check()
        np.subtract(value, previous_value, out=self.dG[slot])
        self.check()
        self.count += 1
        used = min(self.count, self.memory)
        # BLAS in the history's own precision: mixing in float64 would copy the whole history each call.
        products = (self.dF[:used] @ residual.astype(self.dF.dtype, copy=False)).astype(np.float64)
        if previous_residual is self._residual:
            # ΔF_j · ΔF_new = ΔF_j · r_new - ΔF_j · r_old: the history is read once per step, not twice.
            row = products.copy()
            row[:len(self._products)] -= self._products
            row[slot] = float(self.dF[slot] @ self.dF[slot])
        else:
            row = (self.dF[:used] @ self.dF[slot]).astype(np.float64)
        self.gram[slot, :used] = row
        self.gram[:used, slot] = row
        self._residual, self._products = residual, products

    def extrapolate(self, value, residual):
        """The extrapolated next state, or None without history."""
        used = min(self.count, self.memory)
        if used == 0:
            return None
        gram = self.gram[:used, :used] + 1e-10 * np.trace(self.gram[:used, :used]) / used * np.eye(used)
        if residual is self._residual:
            products = self._products
        else:
            products = (self.dF[:used] @ residual.astype(self.dF.dtype, copy=False)).astype(np.float64)
        theta = np.linalg.solve(gram, products)
        return value - (theta.astype(self.dG.dtype) @ self.dG[:used])


    def embed(self, positions, size, residual):
        """Carry the history into another layout of the state, whose entry ``positions[k]`` is this state's entry k
        (-1: dropped; entries no one maps to are 0). ``residual`` is the last pushed residual, already carried."""
        source = np.flatnonzero(positions >= 0)
        target = positions[source]
        for name in ("dF", "dG"):
            old = getattr(self, name)
            new = np.zeros((self.memory, size), dtype=old.dtype)
            for row in range(self.memory):  # row by row: a 2D fancy assignment takes twice as long
                new[row, target] = old[row, source]
            setattr(self, name, new)
            self.check()
        used = min(self.count, self.memory)
        self.gram[:used, :used] = (self.dF[:used] @ self.dF[:used].T).astype(np.float64)
        if self._residual is not None:
            self._residual = residual
            self._products = (self.dF[:used] @ residual.astype(self.dF.dtype, copy=False)).astype(np.float64)
