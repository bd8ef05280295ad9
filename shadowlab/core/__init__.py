"""The framework under every method; nothing here knows about a particular algorithm.

- :mod:`.numerics`: the numerics policy (FMA-opaque products, ordered sums).
- :mod:`.capacity`: power-of-two buckets, padding, overflow flags and retry.
- :mod:`.frame`: a frame's view samples, precision mode and receiver-bias terms.
- :mod:`.result`: ``ShadowResult``, what every method returns.
- :mod:`.counters`: the one table of counter names and meanings.
- :mod:`.sorting`: stable argsort of integer keys by 16-bit radix passes.
- :mod:`.timing`: stage timers with compile time kept apart, and the executable cache.
- :mod:`.io`: atomic output files and provenance.
- :mod:`.jaxcache`: JAX's persistent compilation cache with atomic entries.
"""
