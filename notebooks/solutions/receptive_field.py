"""Exercise (notebook 04): the receptive field of a chain of layers."""


def receptive_field(layers) -> int:
    """Width in input texels that one output texel sees, from ``("conv", k)``, ``("down", 2)``, ``("up", 2)``."""
    r, j = 1, 1  # r: width so far; j: input texels between neighbouring texels at this layer
    for op, k in layers:
        if op == "conv":  # k texels of this layer, j apart
            r += (k - 1) * j
        elif op == "down":  # a 2×2 pool: one more texel of this layer, then texels twice as far apart
            r, j = r + (k - 1) * j, j * k
        else:  # bilinear ×2: mixes two neighbouring coarse texels, then texels half as far apart
            r, j = r + j, j // k
    return r
