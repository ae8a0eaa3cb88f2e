//! The plant's sine, cosine and exponential: every one of Contract 1 goes through here (the
//! simulator, the inverse, the sensitivities), so the plant agrees with itself to the bit
//! whichever implementation is compiled in.
//!
//! By default they are the standard library's (the C library's `sin` and `exp`). With the
//! `libm-sine` feature they are the `libm` crate's (rust-lang's pure-Rust port of musl's fdlibm
//! kernels, < 1 ulp): inlined into the substep, where the C library's is a call, and the same on
//! every platform. It differs from glibc's sine by 1 ulp in about 3 % of arguments, which is
//! what it is for: `bench/identify_perturbed.py` builds the extension with it and asks which of
//! identify's verdicts change when nothing but the last bit of a sine does (on 2026-11-28 five
//! did; docs/identification-speed-log.md, *The plant's sine changed in its last bit*). It was
//! also ~22 % faster per substep side by side; not the default while a verdict still hangs on it.

/// sin(x); NaN for a non-finite x.
#[inline(always)]
pub fn sin(x: f64) -> f64 {
    #[cfg(feature = "libm-sine")]
    {
        libm::sin(x)
    }
    #[cfg(not(feature = "libm-sine"))]
    {
        x.sin()
    }
}

/// (sin(x), cos(x)), the sine bit for bit `sin`'s (what the sensitivities' tangent needs beside
/// the simulator's angle).
#[inline(always)]
pub fn sin_cos(x: f64) -> (f64, f64) {
    #[cfg(feature = "libm-sine")]
    {
        (libm::sin(x), libm::cos(x))
    }
    #[cfg(not(feature = "libm-sine"))]
    {
        (x.sin(), x.cos())
    }
}

/// eˣ.
#[inline(always)]
pub fn exp(x: f64) -> f64 {
    #[cfg(feature = "libm-sine")]
    {
        libm::exp(x)
    }
    #[cfg(not(feature = "libm-sine"))]
    {
        x.exp()
    }
}
