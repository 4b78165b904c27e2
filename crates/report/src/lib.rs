//! What brdfd writes from an estimate for people and for renderers, above the estimation core
//! and nothing else: every result file of an estimate ([`results`]), the glTF and OpenPBR
//! exports fitted to the whole estimate ([`export`]), `report.html` ([`html`]), the pictures
//! of each photo against its re-render ([`compare`]), the judged summary lines ([`summary`]),
//! the broken assumptions the residuals point to ([`flags`]), how much of the room a part's
//! pixels see past the part ([`visibility`]), and the procedural lights reports relight
//! estimates under ([`lights`]).

pub mod compare;
pub mod export;
pub mod flags;
pub mod html;
pub mod lights;
pub mod materials;
pub mod results;
pub mod summary;
pub mod visibility;
