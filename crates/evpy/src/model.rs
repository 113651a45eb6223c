//! `evservo.Mesh`, `render` and `extract_point_set`: object models, the CPU rasterizer and S*.

use crate::camera::PyCamera;
use crate::errors::to_py;
use crate::pose::pose_arg;
use evcore::mesh::{Mesh, Shading, Texture};
use evcore::pointset::{extract_point_set as core_extract, PointSetParams};
use evcore::render::{render as core_render, RenderOptions};
use evcore::Roi;
use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Arc;

/// A triangle mesh in metres (object frame) with grayscale appearance. Immutable and shared.
#[pyclass(name = "Mesh", module = "evservo._evcore", frozen)]
#[derive(Clone)]
pub struct PyMesh {
    pub inner: Arc<Mesh>,
}

fn value_error(msg: String) -> PyErr {
    PyValueError::new_err(msg)
}

/// Face indices from an (M, 3) integer array of any common dtype; negative or oversized → error.
fn faces_from(faces: &Bound<'_, PyAny>) -> PyResult<Vec<[u32; 3]>> {
    let rows: Vec<[i64; 3]> = if let Ok(a) = faces.extract::<PyReadonlyArray2<'_, i64>>() {
        rows3(&a.as_array())?
    } else if let Ok(a) = faces.extract::<PyReadonlyArray2<'_, u32>>() {
        rows3(&a.as_array().mapv(i64::from).view())?
    } else if let Ok(a) = faces.extract::<PyReadonlyArray2<'_, i32>>() {
        rows3(&a.as_array().mapv(i64::from).view())?
    } else if let Ok(a) = faces.extract::<PyReadonlyArray2<'_, u64>>() {
        rows3(&a.as_array().mapv(|v| i64::try_from(v).unwrap_or(-1)).view())?
    } else {
        return Err(value_error(
            "faces must be an (M, 3) integer array (int64, int32, uint32 or uint64)".into(),
        ));
    };
    rows.iter()
        .enumerate()
        .map(|(i, r)| {
            let ok = r.iter().all(|&k| (0..=i64::from(u32::MAX)).contains(&k));
            ok.then(|| r.map(|k| k as u32))
                .ok_or_else(|| value_error(format!("face {i} has an invalid index: {r:?}")))
        })
        .collect()
}

fn rows3<T: Copy>(a: &numpy::ndarray::ArrayView2<'_, T>) -> PyResult<Vec<[T; 3]>> {
    if a.ncols() != 3 {
        return Err(value_error(format!(
            "expected an (N, 3) array, got shape {:?}",
            a.shape()
        )));
    }
    Ok(a.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect())
}

#[pymethods]
impl PyMesh {
    /// Mesh(vertices (N, 3) metres, faces (M, 3) int, vertex_intensity=None (N,), uv=None (N, 2),
    /// texture=None (H, W) float32 in 0..1 with row 0 at the top (v = 1), intensity=0.7).
    /// A texture needs `uv`; without either, `vertex_intensity` or else the constant `intensity`
    /// is the albedo.
    #[new]
    #[pyo3(signature = (vertices, faces, vertex_intensity=None, uv=None, texture=None, intensity=0.7))]
    fn new(
        vertices: PyReadonlyArray2<'_, f64>,
        faces: &Bound<'_, PyAny>,
        vertex_intensity: Option<PyReadonlyArray1<'_, f64>>,
        uv: Option<PyReadonlyArray2<'_, f64>>,
        texture: Option<PyReadonlyArray2<'_, f32>>,
        intensity: f32,
    ) -> PyResult<Self> {
        let verts: Vec<[f32; 3]> = rows3(&vertices.as_array())?
            .into_iter()
            .map(|v| v.map(|c| c as f32))
            .collect();
        let faces = faces_from(faces)?;
        let shading = match (vertex_intensity, uv, texture) {
            (Some(_), Some(_), _) | (Some(_), _, Some(_)) => {
                return Err(value_error(
                    "give either vertex_intensity or uv + texture, not both".into(),
                ))
            }
            (None, Some(uv), Some(tex)) => {
                let uv = uv.as_array();
                if uv.ncols() != 2 {
                    return Err(value_error(format!(
                        "uv must have shape (N, 2), got {:?}",
                        uv.shape()
                    )));
                }
                let t = tex.as_array();
                let (h, w) = t.dim();
                let texture = Texture {
                    width: u32::try_from(w)
                        .map_err(|_| value_error("texture is too wide".into()))?,
                    height: u32::try_from(h)
                        .map_err(|_| value_error("texture is too tall".into()))?,
                    data: t.iter().copied().collect(),
                };
                Shading::Textured {
                    uv: uv
                        .rows()
                        .into_iter()
                        .map(|r| [r[0] as f32, r[1] as f32])
                        .collect(),
                    texture,
                }
            }
            (None, Some(_), None) | (None, None, Some(_)) => {
                return Err(value_error(
                    "a texture needs uv and uv needs a texture".into(),
                ))
            }
            (Some(vi), None, None) => {
                Shading::VertexIntensity(vi.as_array().iter().map(|&v| v as f32).collect())
            }
            (None, None, None) => Shading::Constant(intensity),
        };
        Ok(Self {
            inner: Arc::new(Mesh::new(verts, faces, shading).map_err(to_py)?),
        })
    }

    #[getter]
    fn n_vertices(&self) -> usize {
        self.inner.vertices.len()
    }

    #[getter]
    fn n_faces(&self) -> usize {
        self.inner.faces.len()
    }

    /// Vertices (N, 3) in metres, object frame.
    #[getter]
    fn vertices<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let v = &self.inner.vertices;
        Array2::from_shape_fn((v.len(), 3), |(i, j)| f64::from(v[i][j])).into_pyarray(py)
    }

    /// Radius (metres) of the sphere about the object origin that holds every vertex.
    #[getter]
    fn bounding_radius(&self) -> f64 {
        self.inner.bounding_radius()
    }

    /// Area-weighted surface centroid (3,) in metres, object frame.
    #[getter]
    fn centroid<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let c = self.inner.centroid();
        Array1::from(vec![c.x, c.y, c.z]).into_pyarray(py)
    }

    fn __repr__(&self) -> String {
        let kind = match &self.inner.shading {
            Shading::Constant(a) => format!("constant {a}"),
            Shading::VertexIntensity(_) => "vertex intensity".into(),
            Shading::Textured { texture, .. } => {
                format!("textured {}x{}", texture.width, texture.height)
            }
        };
        format!(
            "Mesh({} vertices, {} faces, {kind})",
            self.inner.vertices.len(),
            self.inner.faces.len()
        )
    }
}

/// Render `mesh` at `T_c_o` (4×4, object in camera) into the camera's pinhole grid (distortion
/// ignored). `roi=(x0, y0, width, height)` renders only that region. Returns a dict with
/// `depth` (H, W) float32 metres (inf on background), `intensity` (H, W) float32, `normal`
/// (H, W, 3) float32 camera-frame unit normals facing the camera, and `roi`.
#[pyfunction]
#[pyo3(signature = (mesh, camera, T_c_o, roi=None, ambient=0.35, diffuse=0.65, background=0.0))]
#[allow(non_snake_case, clippy::too_many_arguments)]
fn render<'py>(
    py: Python<'py>,
    mesh: &PyMesh,
    camera: &PyCamera,
    T_c_o: PyReadonlyArray2<'py, f64>,
    roi: Option<(u32, u32, u32, u32)>,
    ambient: f32,
    diffuse: f32,
    background: f32,
) -> PyResult<Bound<'py, PyDict>> {
    let pose = pose_arg(&T_c_o)?;
    let roi = roi.map(|(x0, y0, width, height)| Roi {
        x0,
        y0,
        width,
        height,
    });
    let opts = RenderOptions {
        ambient,
        diffuse,
        background,
    };
    let (m, cam) = (mesh.inner.clone(), camera.inner);
    let r = py
        .detach(move || core_render(&m, &cam, &pose, roi, &opts))
        .map_err(to_py)?;
    let shape = (r.roi.height as usize, r.roi.width as usize);
    let to_err = |e: numpy::ndarray::ShapeError| value_error(e.to_string());
    let depth = Array2::from_shape_vec(shape, r.depth_m).map_err(to_err)?;
    let intensity = Array2::from_shape_vec(shape, r.intensity).map_err(to_err)?;
    let normal = Array3::from_shape_vec(
        (shape.0, shape.1, 3),
        r.normal_c.into_iter().flatten().collect(),
    )
    .map_err(to_err)?;
    let out = PyDict::new(py);
    out.set_item("depth", depth.into_pyarray(py))?;
    out.set_item("intensity", intensity.into_pyarray(py))?;
    out.set_item("normal", normal.into_pyarray(py))?;
    out.set_item("roi", (r.roi.x0, r.roi.y0, r.roi.width, r.roi.height))?;
    Ok(out)
}

/// (points (K, 3), kinds (K,)) as returned to Python.
type PointsAndKinds<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<u8>>);

/// The model point set S* from one render at `T_c_o` (4×4, object in camera). Returns
/// (points (K, 3) float64 metres in the object frame, kinds (K,) uint8: 0 silhouette, 1 crease,
/// 2 texture). `balance`: share of the points chosen for the pose constraints they add rather
/// than spread evenly. Raises ValueError if the object is out of view or shows fewer than 20 edge
/// pixels.
#[pyfunction]
#[pyo3(signature = (mesh, camera, T_c_o, max_points=1000, seed=0, depth_jump_m=0.01, crease_deg=30.0, texture_grad=0.08, balance=0.0))]
#[allow(non_snake_case, clippy::too_many_arguments)]
fn extract_point_set<'py>(
    py: Python<'py>,
    mesh: &PyMesh,
    camera: &PyCamera,
    T_c_o: PyReadonlyArray2<'py, f64>,
    max_points: usize,
    seed: u64,
    depth_jump_m: f32,
    crease_deg: f32,
    texture_grad: f32,
    balance: f32,
) -> PyResult<PointsAndKinds<'py>> {
    let pose = pose_arg(&T_c_o)?;
    let params = PointSetParams {
        max_points,
        depth_jump_m,
        crease_deg,
        texture_grad,
        balance,
        seed,
        ..PointSetParams::default()
    };
    let (m, cam) = (mesh.inner.clone(), camera.inner);
    let set = py
        .detach(move || core_extract(&m, &cam, &pose, &params))
        .map_err(to_py)?;
    let p = &set.points_o;
    let points = Array2::from_shape_fn((p.len(), 3), |(i, j)| f64::from(p[i][j]));
    let kinds: Vec<u8> = set.kinds.iter().map(|&k| k as u8).collect();
    Ok((points.into_pyarray(py), kinds.into_pyarray(py)))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyMesh>()?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(extract_point_set, m)?)?;
    Ok(())
}
