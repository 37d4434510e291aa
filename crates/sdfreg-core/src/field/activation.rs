//! The softplus activation and its derivatives over a layer's block, vectorised: fast exp and
//! ln(1 + ·) built from FMA where the CPU has it (`multiversion`).

/// `a·b + c`, fused when the caller's instruction set has FMA (`FMA = true`). Without hardware
/// FMA, `mul_add` would call a slow software routine, so the unfused form is used there.
#[inline(always)]
fn madd<const FMA: bool>(a: f32, b: f32, c: f32) -> f32 {
    if FMA {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}

/// `exp(x)` for `x ≤ 0` (f32, relative error < 5e-7), branchless so loops over it vectorise:
/// `2ⁿ · e^r` with `n = round(x / ln 2)`, `|r| ≤ ln2 / 2`, and a degree-6 polynomial for `e^r`.
#[inline(always)]
fn exp_nonpositive<const FMA: bool>(x: f32) -> f32 {
    let x = x.max(-87.0);
    // Round to nearest with the 1.5·2²³ trick (no SSE4.1 `round` needed).
    const MAGIC: f32 = 12_582_912.0;
    let shifted = madd::<FMA>(x, std::f32::consts::LOG2_E, MAGIC);
    let n = shifted - MAGIC;
    // Cody–Waite: ln 2 split in a part exact in f32 and a correction.
    let r = madd::<FMA>(n, -1.428_606_8e-6, madd::<FMA>(n, -0.693_145_75, x));
    let mut p = 1.0 / 720.0;
    for c in [1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0] {
        p = madd::<FMA>(p, r, c);
    }
    // n as an integer from the bits (the same binade as MAGIC, so the low bits are n): unlike
    // `n as i32`, which saturates and runs one lane at a time, this vectorises.
    let n_int = shifted.to_bits().wrapping_sub(MAGIC.to_bits());
    f32::from_bits(n_int.wrapping_add(127) << 23) * p
}

/// `ln(1 + u)` for `u ∈ [0, 1]`, given `t = u / (2 + u) ≤ 1/3` (relative error < 3e-7):
/// `ln(1+u) = 2 atanh(t) = 2 (t + t³/3 + t⁵/5 + …)`, branchless.
#[inline(always)]
fn ln_1p_from_ratio<const FMA: bool>(t: f32) -> f32 {
    let t2 = t * t;
    let mut p = 1.0 / 13.0;
    for c in [1.0 / 11.0, 1.0 / 9.0, 1.0 / 7.0, 1.0 / 5.0, 1.0 / 3.0, 1.0] {
        p = madd::<FMA>(p, t2, c);
    }
    2.0 * t * p
}

/// Softplus and σ are evaluated at `βz` clamped to `±SATURATION`. Beyond it, `e^(−|βz|)` is
/// below 10⁻¹³: under f32's resolution of `βz` itself on the positive side, and on the negative
/// side a value of σ or softplus under 10⁻¹³ instead of a smaller one. Further out the
/// intermediates (`e`, `e/(2+e)`, softplus) reach f32's subnormal range, where x86 takes a
/// microcode assist for every operation on them: a network with large pre-activations (far
/// queries, a baked grid's corners, a learned initialisation) ran several times slower.
/// Measured: `sdfreg eval --shapes ../shared/data/modelnet40-half1 --pairs 36 --protocol all`
/// median per pair 146 → 118 ms (multi-start 32 → 19 ms: the grid it bakes); of the 324
/// pairs' rotation errors 235 the same to the bit, 314 within 0.001°, the largest change
/// 0.27° (a dresser seen in part, 0.49° → 0.22°; a cone 0.1°, the others under 0.05°).
const SATURATION: f32 = 30.0;

/// Numerically stable softplus and σ(βz): returns `(sp(z), σ(βz))`. `inv_beta = 1/β`.
/// One division per call: `1/((1+e)(2+e))` yields both `1/(1+e)` and `e/(2+e)`.
#[inline(always)]
fn softplus_sigmoid<const FMA: bool>(z: f32, beta: f32, inv_beta: f32) -> (f32, f32) {
    let y = beta * z;
    let e = exp_nonpositive::<FMA>((-y.abs()).max(-SATURATION));
    let (a, b) = (1.0 + e, 2.0 + e);
    let r = 1.0 / (a * b);
    let inv = b * r;
    let sp = (y.max(0.0) + ln_1p_from_ratio::<FMA>(e * a * r)) * inv_beta;
    let s = if y >= 0.0 { inv } else { e * inv };
    (sp, s)
}

/// Elementwise kernels of the forward and reverse passes, over contiguous slices so they
/// vectorise; compiled for several instruction sets and chosen at run time.
pub(crate) mod kernels {
    use crate::field::activation::softplus_sigmoid;
    use multiversion::multiversion;

    /// `z += bias` per column; `h = sp(z)`, `s = σ(βz)`. `z`, `h`, `s` are `w × b` column-major.
    #[multiversion(targets("x86_64+avx512f+avx512vl+avx2+fma", "x86_64+avx2+fma", "aarch64+neon"))]
    pub fn activate(z: &mut [f32], h: &mut [f32], s: &mut [f32], bias: &[f32], beta: f32) {
        if multiversion::target::target_cfg_f!(target_feature = "fma") {
            activate_with::<true>(z, h, s, bias, beta)
        } else {
            activate_with::<false>(z, h, s, bias, beta)
        }
    }

    #[inline(always)]
    fn activate_with<const FMA: bool>(
        z: &mut [f32],
        h: &mut [f32],
        s: &mut [f32],
        bias: &[f32],
        beta: f32,
    ) {
        let w = bias.len();
        let inv_beta = 1.0 / beta;
        for ((zc, hc), sc) in z
            .chunks_exact_mut(w)
            .zip(h.chunks_exact_mut(w))
            .zip(s.chunks_exact_mut(w))
        {
            for i in 0..w {
                let zi = zc[i] + bias[i];
                zc[i] = zi;
                let (sp, sg) = softplus_sigmoid::<FMA>(zi, beta, inv_beta);
                hc[i] = sp;
                sc[i] = sg;
            }
        }
    }

    /// `out = a ⊙ b`.
    #[multiversion(targets("x86_64+avx512f+avx512vl+avx2+fma", "x86_64+avx2+fma", "aarch64+neon"))]
    pub fn mul(out: &mut [f32], a: &[f32], b: &[f32]) {
        for ((o, x), y) in out.iter_mut().zip(a).zip(b) {
            *o = x * y;
        }
    }

    /// `acc += a ⊙ b`.
    #[multiversion(targets("x86_64+avx512f+avx512vl+avx2+fma", "x86_64+avx2+fma", "aarch64+neon"))]
    pub fn mul_add(acc: &mut [f32], a: &[f32], b: &[f32]) {
        for ((o, x), y) in acc.iter_mut().zip(a).zip(b) {
            *o += x * y;
        }
    }

    /// `zbar = hbar ⊙ s + β s (1 − s) ⊙ sbar` (the primal pre-activation adjoint).
    #[multiversion(targets("x86_64+avx512f+avx512vl+avx2+fma", "x86_64+avx2+fma", "aarch64+neon"))]
    pub fn primal_adjoint(zbar: &mut [f32], hbar: &[f32], s: &[f32], sbar: &[f32], beta: f32) {
        for (((zb, &hb), &sv), &sb) in zbar.iter_mut().zip(hbar).zip(s).zip(sbar) {
            *zb = hb * sv + sb * beta * sv * (1.0 - sv);
        }
    }

    /// `acc[i] += Σ_j m[i, j]` for a `w × n` column-major `m` with `w = acc.len()`.
    #[multiversion(targets("x86_64+avx512f+avx512vl+avx2+fma", "x86_64+avx2+fma", "aarch64+neon"))]
    pub fn add_columns(acc: &mut [f32], m: &[f32]) {
        let w = acc.len();
        for col in m.chunks_exact(w) {
            for (a, &v) in acc.iter_mut().zip(col) {
                *a += v;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_exp_and_ln_1p_are_accurate() {
        fn worst<const FMA: bool>() -> (f64, f64) {
            let mut worst = (0.0f64, 0.0f64);
            for i in 0..=200_000 {
                let x = -(i as f32) * 4.35e-4; // [−87, 0], below which f32 underflows
                let e = (x as f64).exp();
                worst.0 = worst
                    .0
                    .max(((exp_nonpositive::<FMA>(x) as f64) - e).abs() / e);
                let u = i as f32 / 200_000.0;
                let l = (u as f64).ln_1p();
                let approx = ln_1p_from_ratio::<FMA>(u / (2.0 + u)) as f64;
                worst.1 = worst.1.max((approx - l).abs() / l.max(1e-30));
            }
            worst
        }
        for (name, w) in [("plain", worst::<false>()), ("fused", worst::<true>())] {
            assert!(
                w.0 < 5e-7 && w.1 < 5e-7,
                "{name}: relative errors exp {:.2e}, ln_1p {:.2e}",
                w.0,
                w.1
            );
        }
        assert_eq!(
            exp_nonpositive::<false>(-1000.0),
            exp_nonpositive::<false>(-87.0)
        );
        let (sp, s) = softplus_sigmoid::<false>(0.0, 100.0, 0.01);
        assert!((sp - std::f32::consts::LN_2 / 100.0).abs() < 1e-9 && (s - 0.5).abs() < 1e-7);
        let (sp2, s2) = softplus_sigmoid::<true>(-0.05, 100.0, 0.01);
        assert!(
            (sp2 as f64 - (-5f64).exp().ln_1p() / 100.0).abs() < 1e-9
                && (s2 as f64 - 1.0 / (1.0 + 5f64.exp())).abs() < 1e-8
        );
    }

    #[test]
    fn softplus_and_sigmoid_never_leave_the_normal_range() {
        // Subnormal floats cost a microcode assist per operation on x86: far from zero the
        // activation saturates instead of underflowing through them.
        let normal_or_zero = |v: f32| v == 0.0 || v.is_normal();
        for i in -200_000..=200_000 {
            let z = i as f32 * 1e-4; // βz in [−2000, 2000]
            for fused in [false, true] {
                let (sp, s) = if fused {
                    softplus_sigmoid::<true>(z, 100.0, 0.01)
                } else {
                    softplus_sigmoid::<false>(z, 100.0, 0.01)
                };
                assert!(
                    normal_or_zero(sp) && normal_or_zero(s) && normal_or_zero(1.0 - s),
                    "βz = {}: softplus {sp:e}, σ {s:e}",
                    100.0 * z
                );
            }
        }
        // Saturated, both are what f32 can tell from the exact values.
        let (sp, s) = softplus_sigmoid::<true>(-1.0, 100.0, 0.01);
        assert!(sp > 0.0 && sp < 1e-15 && s > 0.0 && s < 1e-13);
        let (sp, s) = softplus_sigmoid::<true>(1.0, 100.0, 0.01);
        assert!((sp - 1.0).abs() < 1e-6 && s == 1.0);
    }
}
