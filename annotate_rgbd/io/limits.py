"""The sizes an input may have, in one place (no imports: the light commands read them too).

A sequence's lists and images are read within these bounds (:mod:`annotate_rgbd.io.sequence`),
and a run's records are checked against them when read back
(:mod:`annotate_rgbd.report.validation`): a number beyond them is damage, not data.
"""

#: Most frames one stream may list. TUM RGB-D and ICL-NUIM sequences have a few thousand frames;
#: a million is over nine hours at 30 Hz.
MAX_FRAMES = 1_000_000
#: Largest image decoded, in pixels (8192 x 8192, eight times the 3840 x 2160 depth maps of the
#: largest stereo cameras), checked in a PNG's header before decoding: a small file announcing
#: a huge image (a decompression bomb) is refused without allocating it.
MAX_IMAGE_PIXELS = 8192 * 8192
#: Largest timestamp magnitude. 2**63 ns (9.2e18, the end of 64-bit nanosecond clocks) is within,
#: so seconds, milliseconds or nanoseconds since 1970 all pass, and the difference of two
#: timestamps stays finite (1.7e308 - -1.7e308 is infinite).
MAX_TIMESTAMP = 1e19
#: Most planes one run can number: the largest 16-bit plane id (each gets its own colour).
MAX_PLANES = 2**16 - 1
