//! SE(3) helpers over `nalgebra::Isometry3<f64>`. Twists are ξ = (v, ω): translation part first
//! (metres), rotation part second (radians), the order of the paper's pose error e.
//! Increments compose on the left, in the camera frame: T ← exp(ξ)·T.

use crate::error::{Error, Result};
use nalgebra::{
    Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion, Vector3, Vector6,
};

pub type Pose = Isometry3<f64>;

pub fn skew(w: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

/// The left Jacobian V(ω) of SO(3), which maps v to the translation of exp(ξ).
fn left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let theta = w.norm();
    let k = skew(w);
    if theta < 1e-8 {
        return Matrix3::identity() + 0.5 * k;
    }
    let t2 = theta * theta;
    Matrix3::identity()
        + (1.0 - theta.cos()) / t2 * k
        + (theta - theta.sin()) / (t2 * theta) * k * k
}

/// Exponential map of a twist.
pub fn exp(xi: &Vector6<f64>) -> Pose {
    let v = xi.fixed_rows::<3>(0).into_owned();
    let w = xi.fixed_rows::<3>(3).into_owned();
    let rot = UnitQuaternion::from_scaled_axis(w);
    Isometry3::from_parts(Translation3::from(left_jacobian(&w) * v), rot)
}

/// Logarithm: the twist whose exponential is `pose`.
pub fn log(pose: &Pose) -> Vector6<f64> {
    let w = pose.rotation.scaled_axis();
    let v = left_jacobian(&w)
        .try_inverse()
        .unwrap_or_else(Matrix3::identity)
        * pose.translation.vector;
    Vector6::new(v.x, v.y, v.z, w.x, w.y, w.z)
}

/// Unit twist e_k of the k-th degree of freedom (0..3 translation, 3..6 rotation).
pub fn unit_twist(k: usize) -> Vector6<f64> {
    let mut e = Vector6::zeros();
    e[k] = 1.0;
    e
}

/// A 4×4 homogeneous matrix (row-major array) as a pose. Rejects non-finite entries, a bottom
/// row other than (0 0 0 1) and a rotation block that is not orthonormal within 1e-6
/// (the block is then re-orthonormalised so round-off never accumulates).
pub fn pose_from_matrix(m: &[[f64; 4]; 4]) -> Result<Pose> {
    if m.iter().flatten().any(|v| !v.is_finite()) {
        return Err(Error::InvalidArgument(
            "pose contains NaN or infinite entries".into(),
        ));
    }
    let bottom = m[3];
    if bottom[0].abs() > 1e-9
        || bottom[1].abs() > 1e-9
        || bottom[2].abs() > 1e-9
        || (bottom[3] - 1.0).abs() > 1e-9
    {
        return Err(Error::InvalidArgument(format!(
            "pose bottom row must be (0, 0, 0, 1), got {bottom:?}"
        )));
    }
    let r = Matrix3::from_fn(|i, j| m[i][j]);
    let err = (r.transpose() * r - Matrix3::identity()).abs().max();
    if err > 1e-6 || r.determinant() <= 0.0 {
        return Err(Error::InvalidArgument(format!(
            "pose rotation block is not a rotation (orthonormality error {err:.2e}, det {:.3})",
            r.determinant()
        )));
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
    Ok(Isometry3::from_parts(
        Translation3::new(m[0][3], m[1][3], m[2][3]),
        rot,
    ))
}

pub fn pose_to_matrix(pose: &Pose) -> [[f64; 4]; 4] {
    let m: Matrix4<f64> = pose.to_homogeneous();
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

/// Translation distance (metres) and geodesic rotation angle (radians) between two poses.
pub fn distance(a: &Pose, b: &Pose) -> (f64, f64) {
    let d = a.inverse() * b;
    (d.translation.vector.norm(), d.rotation.angle())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_log_round_trip() {
        let xi = Vector6::new(0.1, -0.2, 0.3, 0.4, -0.5, 0.6);
        let back = log(&exp(&xi));
        assert!((back - xi).norm() < 1e-12, "{back}");
    }

    #[test]
    fn exp_matches_first_order_action_for_small_twists() {
        let xi = Vector6::new(1e-6, 2e-6, -1e-6, 3e-6, -2e-6, 1e-6);
        let p = Vector3::new(0.1, 0.2, 0.7);
        let moved = exp(&xi) * nalgebra::Point3::from(p);
        let w = Vector3::new(xi[3], xi[4], xi[5]);
        let linear = p + Vector3::new(xi[0], xi[1], xi[2]) + w.cross(&p);
        assert!((moved.coords - linear).norm() < 1e-11);
    }

    #[test]
    fn matrix_round_trip_and_rejections() {
        let pose = exp(&Vector6::new(0.1, 0.0, 0.5, 0.2, 0.1, -0.3));
        let m = pose_to_matrix(&pose);
        let back = pose_from_matrix(&m).unwrap();
        let (dt, dr) = distance(&pose, &back);
        assert!(dt < 1e-12 && dr < 1e-9);
        let mut bad = m;
        bad[0][1] = f64::NAN;
        assert!(pose_from_matrix(&bad).is_err());
        let mut skewed = m;
        skewed[0][0] *= 1.1;
        assert!(pose_from_matrix(&skewed).is_err());
    }
}
