//! Forward-mode dual numbers with `N` partial derivatives.
//!
//! The catenary and the swivel pulley are closed-form but long chains of `sinh`, `asinh`, `acos`
//! and `atan2`; carrying the partials through the same expressions gives exact (to rounding)
//! Jacobians without a second hand-derived formula that could silently disagree with the first.
//! The tests check them against central finite differences all the same.

use std::ops::{Add, Div, Mul, Neg, Sub};

/// A value and its partial derivatives with respect to `N` inputs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dual<const N: usize> {
    /// The value.
    pub v: f64,
    /// d value / d input k.
    pub d: [f64; N],
}

impl<const N: usize> Dual<N> {
    /// A constant (all partials zero).
    pub fn c(v: f64) -> Self {
        Dual { v, d: [0.0; N] }
    }
    /// Input number `k` with value `v`.
    pub fn var(v: f64, k: usize) -> Self {
        let mut d = [0.0; N];
        d[k] = 1.0;
        Dual { v, d }
    }
    fn chain(self, v: f64, dv: f64) -> Self {
        Dual { v, d: self.d.map(|x| x * dv) }
    }
    /// Square root.
    pub fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        self.chain(s, 0.5 / s)
    }
    /// Hyperbolic sine.
    pub fn sinh(self) -> Self {
        self.chain(self.v.sinh(), self.v.cosh())
    }
    /// Hyperbolic cosine.
    pub fn cosh(self) -> Self {
        self.chain(self.v.cosh(), self.v.sinh())
    }
    /// Inverse hyperbolic sine.
    pub fn asinh(self) -> Self {
        self.chain(self.v.asinh(), 1.0 / (self.v * self.v + 1.0).sqrt())
    }
    /// Arc cosine.
    pub fn acos(self) -> Self {
        self.chain(self.v.acos(), -1.0 / (1.0 - self.v * self.v).sqrt())
    }
    /// `atan2(self, x)`.
    pub fn atan2(self, x: Self) -> Self {
        let r2 = self.v * self.v + x.v * x.v;
        let mut d = [0.0; N];
        for (k, dk) in d.iter_mut().enumerate() {
            *dk = (x.v * self.d[k] - self.v * x.d[k]) / r2;
        }
        Dual { v: self.v.atan2(x.v), d }
    }
    /// Adds a constant to the value (derivatives unchanged).
    pub fn offset(self, c: f64) -> Self {
        Dual { v: self.v + c, d: self.d }
    }
}

impl<const N: usize> Add for Dual<N> {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        let mut d = self.d;
        for (a, b) in d.iter_mut().zip(o.d) {
            *a += b;
        }
        Dual { v: self.v + o.v, d }
    }
}
impl<const N: usize> Sub for Dual<N> {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        self + (-o)
    }
}
impl<const N: usize> Neg for Dual<N> {
    type Output = Self;
    fn neg(self) -> Self {
        Dual { v: -self.v, d: self.d.map(|x| -x) }
    }
}
impl<const N: usize> Mul for Dual<N> {
    type Output = Self;
    fn mul(self, o: Self) -> Self {
        let mut d = [0.0; N];
        for (k, dk) in d.iter_mut().enumerate() {
            *dk = self.d[k] * o.v + self.v * o.d[k];
        }
        Dual { v: self.v * o.v, d }
    }
}
impl<const N: usize> Div for Dual<N> {
    type Output = Self;
    fn div(self, o: Self) -> Self {
        let mut d = [0.0; N];
        for (k, dk) in d.iter_mut().enumerate() {
            *dk = (self.d[k] * o.v - self.v * o.d[k]) / (o.v * o.v);
        }
        Dual { v: self.v / o.v, d }
    }
}
impl<const N: usize> Mul<f64> for Dual<N> {
    type Output = Self;
    fn mul(self, o: f64) -> Self {
        Dual { v: self.v * o, d: self.d.map(|x| x * o) }
    }
}
