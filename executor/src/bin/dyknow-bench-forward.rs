//! `dyknow-bench-forward ENDPOINT IN_KEY OUT_KEY`: a plain Zenoh forwarder (a subscriber that
//! puts every payload it gets on another key), written directly against the `zenoh` crate with
//! no DyKnow in between. The chain benchmark (`benches/chain.rs`) runs one per hop as the
//! baseline for process CUs, as the seed compared its proxy with plain nodelets (Fig. 5.5).

use std::process::ExitCode;

use dyknow_cu::zenoh::{self, Wait};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [endpoint, input, output] = args.as_slice() else {
        eprintln!("usage: dyknow-bench-forward ENDPOINT IN_KEY OUT_KEY");
        return ExitCode::from(64);
    };
    let run = || -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        let session =
            zenoh::open(dyknow_cu::client_config(std::slice::from_ref(endpoint))?).wait()?;
        let publisher = session
            .declare_publisher(output.clone())
            .express(true)
            .wait()?;
        let _subscriber = session
            .declare_subscriber(input.clone())
            .callback(move |sample| {
                let _ = publisher.put(sample.payload().clone()).wait();
            })
            .wait()?;
        // Ready: the chain benchmark waits for this line.
        println!("ready");
        let mut line = String::new();
        // Runs until its standard input closes (the benchmark ends).
        let _ = std::io::stdin().read_line(&mut line);
        Ok(())
    };
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("dyknow-bench-forward: {e}");
            ExitCode::from(1)
        }
    }
}
