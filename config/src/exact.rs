//! Fixed-size arrays read exactly: TOML `[1, 2, 3, 4]` for a point is an error naming the length,
//! never a point cut to its first three numbers.

use serde::de::{Deserializer, Error};
use serde::Deserialize;

fn point<E: Error>(v: Vec<f64>) -> Result<[f64; 3], E> {
    <[f64; 3]>::try_from(v.as_slice())
        .map_err(|_| E::custom(format!("expected exactly three numbers [x, y, z] in m, found {} numbers", v.len())))
}

/// `[x, y, z]`: exactly three numbers.
pub fn three<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
    point(Vec::<f64>::deserialize(d)?)
}

/// An optional `[x, y, z]`: exactly three numbers when given.
pub fn opt_three<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    Option::<Vec<f64>>::deserialize(d)?.map(point).transpose()
}

/// An optional per-axis tolerance: one number for all three axes, or `[x, y, z]`.
pub fn opt_sigma_three<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum ScalarOrThree {
        One(f64),
        Three(Vec<f64>),
    }
    match Option::<ScalarOrThree>::deserialize(d)? {
        None => Ok(None),
        Some(ScalarOrThree::One(s)) => Ok(Some([s; 3])),
        Some(ScalarOrThree::Three(v)) => <[f64; 3]>::try_from(v.as_slice()).map(Some).map_err(|_| {
            D::Error::custom(format!("expected one number (m, every axis) or exactly three [x, y, z], found {} numbers", v.len()))
        }),
    }
}

/// A list of `[a, b, c]` cable-index triples, each of exactly three.
pub fn triples<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<[usize; 3]>, D::Error> {
    Vec::<Vec<usize>>::deserialize(d)?
        .into_iter()
        .enumerate()
        .map(|(k, v)| {
            <[usize; 3]>::try_from(v.as_slice()).map_err(|_| {
                D::Error::custom(format!("entry {k}: expected exactly three cable indices [held, held, reeled], found {}", v.len()))
            })
        })
        .collect()
}
