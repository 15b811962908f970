//! Current-loop execution time, measured with the DWT cycle counter.
//!
//! The counter runs at the core clock; it is enabled in `init`. (QEMU does
//! not model it: there it reads 0 and the measured time is 0; the overrun
//! check then rests on the re-pended trigger interrupt alone.)

/// Cycle count now.
#[inline(always)]
pub fn now_cycles() -> u32 {
    cortex_m::peripheral::DWT::cycle_count()
}

/// Loop timing statistics, shared with telemetry.
#[derive(Clone, Copy, Debug, Default, defmt::Format)]
pub struct LoopTiming {
    /// Cycles of the last current-loop run.
    pub last_cycles: u32,
    /// Largest run so far [cycles].
    pub max_cycles: u32,
    /// Budget [cycles]; longer runs raise the overrun fault.
    pub budget_cycles: u32,
    /// Runs over budget.
    pub overruns: u32,
    /// Current-loop runs.
    pub runs: u32,
}

impl LoopTiming {
    /// Record one run; returns true when it exceeded the budget or when
    /// `repended` (the next period's trigger arrived before the run ended).
    pub fn record(&mut self, cycles: u32, repended: bool) -> bool {
        self.last_cycles = cycles;
        self.runs = self.runs.wrapping_add(1);
        if cycles > self.max_cycles {
            self.max_cycles = cycles;
        }
        let over = cycles > self.budget_cycles || repended;
        if over {
            self.overruns = self.overruns.wrapping_add(1);
        }
        over
    }
}
