"""Exercise (notebook 06): the masked replacement step of controlled generation."""


def masked_step(x, known, mask, t_prev: int, alphas_cumprod, noise):
    """After a reverse step to ``t_prev``: the kept part from ``known`` noised to ``t_prev``, the rest from ``x``."""
    if t_prev < 0:  # the end of the walk: the sample is clean, so is what is kept
        keep = known
    else:
        ab = float(alphas_cumprod[t_prev])
        keep = ab**0.5 * known + (1 - ab) ** 0.5 * noise  # q_sample(known, t_prev)
    return mask * keep + (1 - mask) * x  # 1 = keep
