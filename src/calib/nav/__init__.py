"""Navigation: the numba strapdown engine (``strapdown``, He 2019 eqs. 1-3), the linear error model of a
stationary INS (``errormodel``, He 2019 eqs. 4-8), self-alignment (``alignment``) and streaming navigation of
recordings (``navigation``)."""
