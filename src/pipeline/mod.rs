//! Jobs as the service and the command line run them: the synchronous
//! `treemorph-pipeline` crate (one [`JobSpec`] per request, the runner, the
//! error-code table), re-exported here so the service's modules name it as
//! `crate::pipeline`.

pub use treemorph_pipeline::*;
