"""Fast CPU paths for two of the method's operations, outside the core that states the method.

``pointops``: the decoder's point MLPs in cache-sized chunks with their own backward, and the triplane
lookup's backward as an ``index_add``; ``bf16ops``: the same MLPs under bf16 autocast, for training and for
decoding; ``planeops``: the cross-plane rollout's repeated means as 1D convolutions. The plain modules in
``model/`` say what is computed; these compute the same (pinned by ``tests/test_pointops.py`` and
``tests/test_unet.py``, within float tolerance, a decode in bf16 bit for bit) in less time, on the CPU.
"""
