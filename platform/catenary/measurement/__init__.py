"""Run file to per-span wear: recording, vehicle compensation, wear, the measurement chain,
chainage, the mast register, spans, samples, ``process`` and the comparison of runs."""
