//! A dora relay: forwards every input `in` to its output `out` unchanged (the Arrow array
//! as received; dora only re-frames it for the wire).

use dora_node_api::{DoraNode, Event, dora_core::config::DataId};

fn main() -> eyre::Result<()> {
    dyknow_dora_chain::init_log();
    let (mut node, mut events) = DoraNode::init_from_env()?;
    let out = DataId::from("out".to_owned());
    while let Some(event) = events.recv() {
        if let Event::Input { metadata, data, .. } = event {
            node.send_output(out.clone(), metadata.parameters, data)?;
        }
    }
    Ok(())
}
