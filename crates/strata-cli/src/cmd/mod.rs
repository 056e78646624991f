//! One module per subcommand.

pub(crate) mod bench;
pub(crate) mod codecs;
pub(crate) mod compare;
pub(crate) mod composite;
pub(crate) mod dataset;
pub(crate) mod demo;
pub(crate) mod display;
pub(crate) mod inspect;
pub(crate) mod learn;
pub(crate) mod learn_eval;
pub(crate) mod methods;
pub(crate) mod mfr;
pub(crate) mod mfr_slow;
pub(crate) mod node;
pub(crate) mod render;
pub(crate) mod scenes;
pub(crate) mod tfss_sim;
pub(crate) mod view;
