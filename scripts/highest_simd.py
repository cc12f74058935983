"""Print the SIMD features to switch off (NPY_DISABLE_CPU_FEATURES) so that numpy computes as on a
CPU one level below this one: on an AVX-512 machine "X86_V4 AVX512_ICL AVX512_SPR" (it then runs
its AVX2 code), on an AVX2 one "X86_V3" (SSE4.2 code). Prints nothing where numpy dispatches to no
feature above its baseline. Used by .ci/run for its second pass of the float-sensitive tests.
"""
from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

found = [f for f in __cpu_dispatch__ if __cpu_features__.get(f)]
top = [f for f in found if f == "X86_V4" or f.startswith("AVX512")] or found[-1:]
print(" ".join(top))
