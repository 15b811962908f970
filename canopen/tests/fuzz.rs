//! Property tests: arbitrary frames never panic the node, and every SDO
//! abort leaves the dictionary, the profile and the device unchanged.
// Test support outside `#[test]` functions: unwrapping and indexing a
// fixture is the test failing, which is what it should do.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

mod common;

use common::*;
use foc_canopen::CanFrame;
use proptest::prelude::*;

fn sdo_frame() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        // Mostly well-formed: a known command specifier, a real index.
        (
            prop::sample::select(vec![
                0x00u8, 0x10, 0x20, 0x21, 0x22, 0x23, 0x27, 0x2B, 0x2F, 0x40, 0x60, 0x70, 0x80,
                0xA0, 0xC0, 0xE0
            ]),
            prop::sample::select(
                foc_canopen::od::OBJECTS
                    .iter()
                    .map(|d| (d.index, d.sub))
                    .collect::<Vec<_>>()
            ),
            any::<[u8; 4]>(),
        )
            .prop_map(|(cs, (i, s), d)| {
                let [i0, i1] = i.to_le_bytes();
                vec![cs, i0, i1, s, d[0], d[1], d[2], d[3]]
            }),
        any::<[u8; 8]>().prop_map(|a| a.to_vec()),
        prop::collection::vec(any::<u8>(), 0..=8),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn sdo_requests_never_panic_and_aborts_change_nothing(reqs in prop::collection::vec(sdo_frame(), 1..12)) {
        let mut b = Bench::new();
        for req in reqs {
            let before = b.state();
            b.sent.clear();
            b.frame(0x600 + u16::from(ID), &req);
            let out = b.take();
            prop_assert!(out.len() <= 1);
            if let Some(r) = out.first() {
                prop_assert_eq!(r.id, 0x585);
                prop_assert_eq!(r.len, 8);
                if r.data[0] == 0x80 {
                    prop_assert_eq!(b.state(), before, "abort {:x?} after {:x?}", r.data, req);
                }
            }
        }
    }

    #[test]
    fn any_frame_in_any_state_never_panics(
        frames in prop::collection::vec((0u16..0x800, prop::collection::vec(any::<u8>(), 0..=8), any::<bool>()), 1..40),
        start in any::<bool>(),
    ) {
        let mut b = Bench::new();
        if start {
            b.start();
        }
        for (k, (id, data, rtr)) in frames.into_iter().enumerate() {
            let f = if rtr { CanFrame::remote(id, data.len() as u8).unwrap() } else { CanFrame::new(id, &data).unwrap() };
            let sent = &mut b.sent;
            b.node.on_frame(&f, b.now_us, &mut b.dev, &mut |f| sent.push(f));
            b.tick_to(1000 * (k as u64 + 1));
        }
        for f in b.take() {
            prop_assert!(f.id <= 0x7FF && f.len <= 8);
        }
    }
}
