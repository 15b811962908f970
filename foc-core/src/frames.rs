//! Reference-frame value types.
//!
//! The same three structs carry currents (A) and voltages (V); the variable
//! name says which (`i_dq`, `v_ab`, ...). Keeping the frame in the type means
//! a phase quantity can never be passed where a rotor-frame one is expected.
//!
//! ```
//! use foc_core::frames::{Abc, Dq};
//! let i_abc = Abc::new(1.0, -0.5, -0.5); // [A]
//! assert!(i_abc.sum().abs() < 1e-6);
//! let v_dq = Dq::new(0.0, 2.0); // [V]
//! assert_eq!(v_dq.magnitude(), 2.0);
//! ```

/// Three phase quantities (stator, phases A, B, C).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Abc {
    /// Phase A.
    pub a: f32,
    /// Phase B.
    pub b: f32,
    /// Phase C.
    pub c: f32,
}

impl Abc {
    /// New value from the three phases.
    pub const fn new(a: f32, b: f32, c: f32) -> Self {
        Self { a, b, c }
    }
    /// `a + b + c` (zero for a star winding; see design §2).
    #[inline]
    pub fn sum(&self) -> f32 {
        self.a + self.b + self.c
    }
    /// True when all three are finite.
    #[inline]
    pub fn is_finite(&self) -> bool {
        self.a.is_finite() && self.b.is_finite() && self.c.is_finite()
    }
    /// As an array `[a, b, c]`.
    #[inline]
    pub const fn to_array(self) -> [f32; 3] {
        [self.a, self.b, self.c]
    }
}

/// Stationary two-axis frame (alpha along phase A, beta 90 deg ahead).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AlphaBeta {
    /// Alpha axis component.
    pub alpha: f32,
    /// Beta axis component.
    pub beta: f32,
}

impl AlphaBeta {
    /// New value.
    pub const fn new(alpha: f32, beta: f32) -> Self {
        Self { alpha, beta }
    }
    /// Vector length.
    #[inline]
    pub fn magnitude(&self) -> f32 {
        crate::sqrtf(self.alpha * self.alpha + self.beta * self.beta)
    }
    /// True when both components are finite.
    #[inline]
    pub fn is_finite(&self) -> bool {
        self.alpha.is_finite() && self.beta.is_finite()
    }
}

/// Rotor frame: d along the rotor flux, q 90 electrical degrees ahead.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Dq {
    /// Direct (flux) axis component.
    pub d: f32,
    /// Quadrature (torque) axis component.
    pub q: f32,
}

impl Dq {
    /// New value.
    pub const fn new(d: f32, q: f32) -> Self {
        Self { d, q }
    }
    /// Zero vector.
    pub const ZERO: Self = Self { d: 0.0, q: 0.0 };
    /// Vector length.
    #[inline]
    pub fn magnitude(&self) -> f32 {
        crate::sqrtf(self.d * self.d + self.q * self.q)
    }
    /// True when both components are finite.
    #[inline]
    pub fn is_finite(&self) -> bool {
        self.d.is_finite() && self.q.is_finite()
    }
}
