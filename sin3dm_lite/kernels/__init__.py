"""Fast CPU paths for the method's operations, outside the core that states the method.

``pointops``: the decoder's point MLPs in cache-sized chunks with their own backward, and the triplane lookup's
backward as an ``index_add``; ``bf16ops``: the same MLPs under bf16 autocast; ``planeops``: the denoiser's cross-plane
rollout's repeated means as 1D convolutions, its time-step modulation folded into a GroupNorm, its 1×1 convolutions and
upsampling as products. They compute what the plain modules in ``model/`` compute
(``tests/test_pointops.py`` and ``tests/test_unet.py`` pin them), in less time.
"""
