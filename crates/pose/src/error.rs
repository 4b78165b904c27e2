//! What can go wrong in finding a pose, by what the user can do about it: fix the board file,
//! retake a photo, set the rig's camera, or place the object again.

/// A pose that could not be found, and why.
#[derive(Debug, thiserror::Error)]
pub enum PoseError {
    /// The board file's numbers make no board brdfd can draw and find (sizes, marker share,
    /// dictionary, placement).
    #[error("{0}")]
    Board(String),
    /// The drawing library refused a board the file describes (it does not fit a page).
    #[error("{what}: {reason}")]
    Drawing { what: &'static str, reason: String },
    /// No board in a photo.
    #[error("{0}")]
    BoardNotFound(String),
    /// A named photo's problem. The problem is the source, not also the message: a chain
    /// printed whole (anyhow's `{:#}`, the rig's `said`) would say it twice.
    #[error("{photo}")]
    InPhoto {
        photo: String,
        #[source]
        source: Box<PoseError>,
    },
    /// Photos that do not fit the rig's camera or each other, or none at all.
    #[error("{0}")]
    Photos(String),
    /// The rig's camera cannot be posed so (an orthographic camera has no pose to find).
    #[error("{0}")]
    Camera(String),
    /// The board's corners were found but give no pose.
    #[error("the board's corners give no pose: {0}")]
    NoPose(String),
    /// The object's outline cannot be matched to the mesh where the rig places it.
    #[error("{0}")]
    Silhouette(String),
}

pub type Result<T> = std::result::Result<T, PoseError>;

/// Returns a [`PoseError`] of the kind named, with a message formatted as `format!` does.
macro_rules! fail {
    ($kind:ident, $($arg:tt)*) => {
        return Err($crate::error::PoseError::$kind(format!($($arg)*)))
    };
}
pub(crate) use fail;
