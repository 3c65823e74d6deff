//! One message through each transport inside one process: publish (iceoryx2: loan, write,
//! send, notify; uds: one datagram per subscriber) and receive, for a `RobotState` (176
//! bytes). The cross-process figures come from `scl bench latency`.
//!
//! Run: `cargo bench -p transport --bench transport`.
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use ipc_types::{Prefix, RobotState, Transport};
use std::hint::black_box;
use transport::Graph;

fn bench(c: &mut Criterion) {
    for transport in [Transport::Iceoryx2, Transport::Uds] {
        let prefix = Prefix::new(&format!("cb{}{transport}", std::process::id())).unwrap();
        let g = Graph::join_with(&prefix, "bench", transport).unwrap();
        let sub = g.robot_state_subscriber(true).unwrap();
        let publ = g.robot_state_publisher().unwrap();
        let mut s = RobotState::at_rest(0, 0, 6);
        c.bench_function(&format!("{transport}: send + receive RobotState"), |b| {
            b.iter(|| {
                s.tick += 1;
                publ.send(black_box(s)).unwrap();
                black_box(sub.latest().unwrap())
            })
        });
        drop((sub, publ, g));
        let _ = transport::graph::release_domain(&prefix);
        transport::uds::remove_graph(prefix.as_str());
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
