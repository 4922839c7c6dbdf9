"""The tolerances, sizes and limits of bderiv that Python code reads, each with where it
comes from.

What is here: a number whose value is a choice someone may question or tune (a tolerance:
an accepted error, a step, a margin; a size: rows, bytes or queries handled at a time; a
limit: the most of something a call takes or makes), and any default used in more than one
place. Each has a ``#:`` line saying what it is and where its value comes from: a
measurement (which), a standard (which) or a judgement (why).

What stays beside its code: a method's own data (the coefficients and step control of
DOP853, the levels and order of the runs of ``_numdiff``'s extrapolation), the layout of
one kernel (lanes, groups and lock widths: the code is written for them), codes, formats
and signatures (status codes, file versions, field names), facts that are no choice (63
events in an int64 mask, the smallest normal float64), the probe of a check whose outcome
does not depend on it (``_cyclic.SHIFTS``), and what one command or figure shows (rows
listed, samples drawn, colours).

The numbers that njit code reads are in ``bderiv._numerics``: numba compiles them in, so
that file keys the kernels' disk caches; this one keys none (editing a default here
compiles nothing again). No njit function may read a value of this module
(``tests/test_numerics.py``).

This module imports nothing of bderiv: with ``_numerics``, the bottom of the layers
(docs/design.md); every module, the kernels included, may import both. To change a value,
change it here: modules take the value when they import it, so assigning to this module at
run time changes nothing.
"""

from __future__ import annotations

# --- integration ------------------------------------------------------------------------

#: the most steps a run's ``max_step`` may force (``t_final / max_step``): beyond, refused
#: before the run (1e-300 ran for minutes on the compiled integrator until its record
#: outgrew the memory, and without end on scipy)
MAX_FORCED_STEPS = 1e10

#: default relative and absolute tolerance of the integrators (``SolverOptions``, the
#: compiled ``integrate_stretch``): a judgement, about ten digits of the state, well
#: above what the integrators can reach (MIN_RTOL) and cheap enough for the default.
DEFAULT_RTOL = 1e-10
DEFAULT_ATOL = 1e-12
#: default largest number of event groups of one run (a Zeno or chattering trajectory
#: would otherwise never end): a judgement, enough for hundreds of strides of a
#: many-legged gait.
MAX_GROUPS = 10_000
#: impacts of one event looked at for an accumulation (Zeno, ``models/events/zeno.py``):
#: their four intervals must shrink as a geometric sequence to zero (a judgement: two
#: consecutive estimates of the limit of the intervals must agree with it).
ZENO_IMPACTS = 5
#: how close to zero the intervals' limit must be, relative to the last interval, for the
#: impacts to accumulate (a judgement: a gait converging to its period has a limit near
#: its step time; rounding of the event times is far below it).
ZENO_LIMIT_RTOL = 0.1
#: the longest a slice of the compiled driver runs, in seconds, between which Ctrl-C and
#: progress are seen (a judgement: an answer to Ctrl-C within a fifth of a second).
SLICE_SECONDS = 0.2
#: accepted steps of a slice before the model's cost per step is known (a judgement: few
#: enough that the first slice stays short on a costly model).
FIRST_SLICE = 256

# --- events at a stop -------------------------------------------------------------------

#: default ``simultaneity_tol`` of ``simulate`` and ``simulate_many``: events whose
#: first-order time to crossing is at most this switch together at a stop (a judgement:
#: only events all but at the stop together, so that a simulation keeps every order the
#: integrator resolves; the B-derivatives group more widely, below).
SIMULATION_SIMULTANEITY_TOL = 1e-12
#: default ``simultaneity_tol`` of the B-derivatives along trajectories (flow maps, return
#: maps, periodic orbits, ``bderiv.jax.flow``): a judgement, well above the event-location
#: accuracy of the default tolerances, so that events that coincide in the model are one
#: group (their points must also agree to within the integration accuracy).
DERIVATIVE_SIMULTANEITY_TOL = 1e-7
#: ``simultaneity_tol`` of the finite differences (``checks``): far below the event-time
#: spread ``eps |v|`` of a perturbed start, so that the events of a perturbed trajectory
#: switch one by one, in their true order.
FD_SIMULTANEITY_TOL = 1e-13
#: relative accuracy to which a model's resets are checked: with analytic Jacobians (event
#: and reset; the default ``reset_tol`` of ``BDerivative``), and with numerical ones
#: (accurate to ``ACCEPT_RTOL`` or refused, so checked at ten times it).
RESET_TOL = 1e-9
RESET_TOL_NUMERICAL = 1e-6
#: largest accepted ``|events(rho)|`` at an event point (``HybridSystem.bderivative``) and
#: ``|section(x0)|`` at a section point (``return_map``; the orbit's iterates): a
#: judgement, far above the rounding of an event function at unit scale, far below a point
#: visibly off the surface.
ON_SURFACE_TOL = 1e-9

# --- the excursion screen (surfaces crossed and crossed back inside a step) ------------

#: time accuracy of a peak, relative to its bracket: ``h`` is flat at a peak, so its value
#: is found to about the curvature times this squared (1e-14 of the bracket's scale).
PEAK_XTOL = 1e-7

# --- derivatives of user functions (``_numdiff``, the compiled Jacobians) ---------------

#: the first step of an extrapolation run relative to the variable's scale (a judgement:
#: large, the extrapolation removes the truncation; smaller steps follow).
BASE_STEP = 2.0**-3
#: an extrapolation stops at this relative error (of the entry, or of the row); an entry
#: above ACCEPT_RTOL is refused (a judgement: half the digits of float64 at worst).
TARGET_RTOL = 1e-10
ACCEPT_RTOL = 1e-7
#: every entry is accurate to ACCEPT_RTOL relative to itself, or to this fraction of its
#: row's largest entry, or to ROUND_FLOOR times the rounding of the function's value over
#: the variable's scale (``eps |f_i(x)| / s_j``): an entry 0 at x is known to no better.
ROW_FLOOR = 2.0**-40
ROUND_FLOOR = 2.0**10
#: a given Jacobian passes if ``|J v - D_v f|`` is within CHECK_RTOL relative to
#: ``|J| |v|`` (plus CHECK_ERROR_FACTOR times the difference's error estimate): far above
#: what rounding and the extrapolation leave (about 1e-10), far below a wrong term.
CHECK_RTOL = 1e-6
CHECK_ERROR_FACTOR = 8.0
#: and a mismatch within CHECK_ROUND_FLOOR eps of the largest output's ``|J| |v|`` passes
#: too: an output that cancels to rounding (a body's angular acceleration of 1e-15 beside
#: its 9.81 fall) has differences of that size whatever its Jacobian says, and no smaller
#: wrong term can be told from them
CHECK_ROUND_FLOOR = 64.0
#: rows of a command's random batch drawn at once (``cli.systems.random_vectors``): about
#: 0.1 s of NumPy for d = 6, so Ctrl-C is seen between draws (one draw of 30 million rows
#: held it for 3-4 s)
RANDOM_ROWS = 1 << 20
#: the step across each surface (relative to the state's scale) at which a region's
#: field is compared on its two sides at an event point (``analysis.assembly``; a
#: judgement: far above rounding, below the features an integrator resolves, so that a
#: steep but smooth field is not taken for a switch)
SIDE_STEP = 1e-8
#: and the factor it then shrinks by: a jump that stays is a field that switches on the
#: state, not on its mask; a smooth field's change (or a kink's) shrinks with the step
SIDE_SHRINK = 16.0
#: the least spread of a growth rate's log (``analysis.stability``): a map evaluated in
#: float64 moves ``log |A v|`` by rounding at every step (a ball with e = 1, whose apex map
#: is the identity, gave 1 + 4e-16 and "unstable"), so a rate within this of 1 is
#: "undecided" (a judgement: rounding of a few thousand operations per step)
RATE_ROUNDING = 2.0**-40
#: a build (flow map, return map) longer than this, most of it in numerical Jacobians, is
#: reported at WARNING (``models.calls``; a judgement: a pause a user notices)
SLOW_BUILD_SECONDS = 2.0
#: seconds that a new model's numba functions take on their Python code in its runs before
#: they are compiled (``models.calls.starts_in_python``; about what compiling them takes,
#: 1.5 to 2.5 s for the chair's): a first answer that needs less comes without compiling
#: them, and work that needs more spends at most this on Python (docs/design.md, "Python
#: first")
PYTHON_FIRST_SECONDS = 1.0
#: largest number of masks ``check_jacobians`` checks by default (all 2**n up to n = 8;
#: a judgement of cost: each mask is a Jacobian by differences).
DEFAULT_MASKS = 1 << 8

# --- B-derivatives: tables, fast paths, scaling -----------------------------------------

#: entries of a fast path that must agree may differ by this times their own rounding
#: scale (rounding of a dot product of d terms is ~ d * 1.1e-16 of that scale).
FAST_RTOL = 1e-12
#: structured corners: transversality counts as proved when the lower bound on every rate
#: exceeds this fraction of the sum of the magnitudes it adds up (the rates are updated
#: along a chain by n + p additions, whose rounding is ~ (n + p) EPS of that sum, far below
#: this).
PROOF_MARGIN = 1e-9
#: a rate whose factors multiply below 10**UNDERFLOW_LOG10 is lost to underflow (float64
#: underflows below 1e-308; the margin leaves room for the products of a chain).
UNDERFLOW_LOG10 = -290
#: tables whose largest entry (of a row of Dh, or of F as a whole) is beyond
#: 2**+-TABLE_BAND are scaled by a power of two at build; within it the products of the
#: kernels stay far from both ends of the float64 range (2**+-1022), and nothing is copied.
TABLE_BAND = 64
#: the largest n for which a model's dense table (2**n rows) is built on request
#: (``corner_points``, ``triangulation``, ``table``): 2**20 rows of F, 160 MiB at d = 20.
MAX_TABLE_EVENTS = 20
#: default cap on the number of pieces ``pieces()`` and ``triangulation()`` will build
#: (8!: every order of 8 events).
MAX_PIECES = 40320

# --- kernels and threads ----------------------------------------------------------------

#: batches smaller than this run on one thread (thread start-up costs more than it saves).
PARALLEL_MIN_QUERIES = 1024
#: work per kernel launch, in units of n (n + d) (about a nanosecond each). Ctrl-C is seen
#: between launches only, so a long batch is cut into launches of about 0.05 to 0.3 s;
#: a launch wakes the threads, which costs more on a busy machine, so not shorter.
LAUNCH_WORK = 1 << 25
#: seconds a launch of a block whose cost per query is not known (a user's corner function,
#: called n + 1 times per query) is sized to, from the last launch's time: at n = 128 a
#: launch of LAUNCH_WORK's 2**14 queries took up to 20 s, Ctrl-C waiting for it
LAUNCH_SECONDS = 0.2
#: row scaling: batches with fewer entries (rows x d) are scaled serially: measured (load 8
#: on 2 cores) 0.7-1.8 ns per entry serially, a parallel launch 13-34 us when its threads
#: get cores at once and 11-16 ms when they wait (318 launches on (200, 8) batches were 6 of
#: the 7 s of a stability verdict); below 2**18 entries (about 0.3 ms of serial work)
#: parallel saves at most half of that and risks 16 ms.
SERIAL_ENTRIES = 1 << 18
#: records larger than this are prefetched one step ahead by the lane kernels (about the
#: size of the last-level cache share of a core; below it the hint costs more than it saves)
FAR_BYTES = 4 << 20
#: a default memory limit is not read for a need up to this many bytes (1 MiB): the limit
#: guards against the 2**n rows of many events (or a huge file) exhausting the machine, and
#: a process that got this far already holds over 100 MiB (numpy, numba and the compiled
#: kernels), so 1 MiB more is never what runs it out. Reading /proc/meminfo costs tens of
#: microseconds, a sizeable part of a small BDerivative's construction (two per build of a
#: flow map with one event group); dense tables of d = 8 reach 1 MiB at n = 12.
SMALL_NEED_BYTES = 1 << 20
#: bytes a run of ``simulate_many`` holds besides its samples' arrays and its final state
#: (the Trajectory, its empty record and the batch's slots: measured 817 B a run of the
#: compiled pronking gait that met no event and kept no sample, d = 4), and besides the
#: states in it, each event group with its event record (measured 565 B at d = 4); the
#: batch's size is checked before its runs and again as their results grow
RUN_HELD_BYTES = 720
GROUP_HELD_BYTES = 500
#: address space a kernel's compilation may take (LLVM; measured 50 to 70 MiB for the
#: drivers of a small dense map), with a margin
COMPILE_BYTES = 128 << 20
#: address space a thread takes besides its stack (guard page, TLS, the runtime's own
#: structures; glibc's malloc arena of a thread is reserved only when it fits)
THREAD_EXTRA_BYTES = 2 << 20

# --- blocks and chunks (memory at a time) -----------------------------------------------

#: rows per chunk when chunking is implied (a ``progress`` callback or a memmap input) and
#: no ``chunk_size`` is given, at most: 2**16 rows of d = 128 are 64 MiB, and a chunk is
#: long enough to keep two threads busy. The chunks are sized by their time: the first of
#: ``FIRST_CHUNK_ROWS``, each next one to ``CHUNK_SECONDS`` by the last one's time, so that
#: progress is reported every second or so however slow the rows are (a corner function
#: at n = 128: 2**16 rows took 100 s before the first report)
DEFAULT_CHUNK_ROWS = 1 << 16
FIRST_CHUNK_ROWS = 1 << 12
CHUNK_SECONDS = 0.5


def sized_by_time(rows: int, took: float, seconds: float, low: int, high: int) -> int:
    """The rows of the next launch or chunk: as many as the last (``rows`` in ``took``
    seconds) would run in ``seconds``, within ``[low, high]`` (the rule of the kernels'
    timed launches and of the batches' default chunks).

    Examples
    --------
    >>> sized_by_time(1000, 0.1, 0.5, 64, 1 << 16), sized_by_time(1000, 10.0, 0.5, 64, 9999)
    (5000, 64)
    """
    return int(min(max(rows * seconds / max(took, 1e-6), low), high))


#: rows of a batch above which it is chunked all the same (``DEFAULT_CHUNK_ROWS``): a
#: batch in one call held Ctrl-C for seconds (5e6 rows of d = 30: 0.6 to 2.9 s, its
#: scaling step one call over all rows); 2**20 keeps the benchmarks' 10**6 in one call
IMPLICIT_CHUNK_ROWS = 1 << 20
#: rows per block when a table is built or scanned; 2**15 rows of 20 float64 are 5 MiB.
BLOCK_ROWS = 1 << 15
#: rows per BLAS call when the rates of the region records are built. Products this small
#: run on one BLAS thread; one big call spreads over BLAS threads, which on a shared 2-core
#: machine was measured 5x to 50x slower (n = d = 20: 0.09 s in blocks of 512 rows, 0.5 s
#: to 5 s in one call or in blocks of 2**11..2**15 rows, depending on the other load).
RATE_BLOCK_ROWS = 512
#: bytes of the temporaries of one chunk of ``Linearisation.piece_matrices`` (each row is
#: d queries: the repeated rows, the unit vectors and the columns, d * d floats each): a
#: judgement, as CHAIN_BYTES.
PIECE_CHUNK_BYTES = 64 << 20
#: bytes of chain corners gathered at a time by the generic ``Engine.tangents`` (a
#: judgement: large enough that the per-chunk overhead vanishes, small beside memory).
CHAIN_BYTES = 64 << 20
#: masks per block of the existence check of resets (each block holds a few (m, d, d)
#: products; a judgement).
CHECK_ROWS = 1 << 10
#: queries per chunk of the NumPy baseline; its temporaries are a few (chunk, n) and
#: (chunk, d) arrays, which then stay in L2. Measured best of 1024..65536 on 2 cores.
NUMPY_CHUNK = 4096
#: side of the square product whose rate ``measure_blas_rate`` measures (a judgement:
#: large enough for BLAS to reach its blocked rate, small enough to take milliseconds).
BLAS_SIZE = 512

# --- periodic orbits and checks ---------------------------------------------------------

#: default of ``periodic_orbit``: stop when ``max |P(x) - x| <= ORBIT_TOL * max(1, |x|)``,
#: after at most ORBIT_MAX_ITER Newton iterations (a judgement: two orders above the
#: integration accuracy of ``orbit.ORBIT_OPTIONS``, rtol 1e-12, which the residual cannot
#: beat; Newton's method converges in a few steps where it converges at all).
ORBIT_TOL = 1e-10
ORBIT_MAX_ITER = 30
#: longest wait for the return without a period guess (also ``return_map``'s default),
#: and in multiples of the guess.
DEFAULT_T_MAX = 100.0
T_MAX_PER_PERIOD = 3.0
#: halvings of a Newton step that does not reduce the residual before giving up (a
#: judgement: a step shrunk by 2**-10 that still does not help is not worth taking).
MAX_HALVINGS = 10
#: a piece's solution lies in its piece when ``|A(delta) - A_piece delta|`` is below
#: this times ``|A_piece| |delta|`` (ties between pieces give equal values).
PIECE_RTOL = 1e-8
#: pieces tried by one Newton step before it settles for a generalized Newton step.
MAX_PIECE_SWITCHES = 32
#: pieces whose Floquet multipliers ``stability()`` reports: the most visited.
MULTIPLIER_PIECES = 12
#: a shifted return that differs from the shifted original by more than this times
#: ``max(1, |x|)`` shows that a coordinate is not cyclic (a judgement: well above the
#: integration error of a return, far below a real dependence).
INDEPENDENCE_RTOL = 1e-7
#: the return map's derivative along a cyclic coordinate that differs from the identity
#: by more than this times ``max(1, |image|)`` shows that it is not cyclic (a judgement:
#: ten times the accepted error of a numerical Jacobian entry, ``ACCEPT_RTOL``; a model
#: that does not read the coordinate gives exactly the identity).
EQUIVARIANCE_RTOL = 1e-6
#: strides a direction of ``decay_check`` needs in the linear regime for its rate to be
#: fitted (a line through fewer points has no check of its own).
MIN_FIT_STRIDES = 3
#: the linear regime of ``decay_check``: deviations at most this fraction of |x0| (of
#: 1 when x0 = 0), where the model's nonlinearity is still small
LINEAR_STATE = 0.05
#: worker processes of ``stability_map(client="local")`` (one per core of this project's
#: machines)
LOCAL_WORKERS = 2

# --- contacts (``symbolic.contacts``, ``robots.rigid``) ----------------------------------

#: another contact is hit "at the same instant" as an impact (``symbolic.contacts``'
#: ``ImpactCheck``, a rigid robot's reset) when its first-order time to contact, gap over
#: closing speed, is at most this, in seconds: the widest default grouping of the library's
#: runs (the B-derivatives', DERIVATIVE_SIMULTANEITY_TOL; simulate's is 1e-12), so that the
#: groups they make of coupled impacts are refused by name, and a contact reached
#: measurably later is not counted (a gap of 1e-6 counted whatever the speed refused a
#: wall hit 5 ms later)
IMPACT_SIMULTANEITY_TOL = DERIVATIVE_SIMULTANEITY_TOL
#: relative coupling ``|J_i M^-1 J_j^T| / sqrt(J_i M^-1 J_i^T J_j M^-1 J_j^T)`` accepted
#: between simultaneous contacts (a judgement: orthogonal contacts give rounding only,
#: about 1e-16; coupled ones give a number of order one)
COUPLING_TOL = 1e-9

# --- the command line ---------------------------------------------------------------------

#: default steps of the finite differences (``checks.fd_check``, ``bderiv demo --eps``, the
#: gait and landing summaries): three decades, so that the error's fall with the step is
#: seen (first order), each far above EPS_RANGE's rounding floor
FD_EPS = (1e-4, 1e-5, 1e-6)
#: default tangent vectors of ``bderiv demo``'s timed batch, and of its finite-difference
#: check (a judgement: a batch long enough to time both threads; a check of a few
#: vectors, each a pair of simulations per step)
DEMO_BATCH = 1_000_000
DEMO_CHECK = 8
#: default numbers of events, queries per batch and timed runs (the best kept) of
#: ``bderiv bench`` (a judgement: a short sweep; the best of three runs tames the noise of
#: a shared machine)
BENCH_NS = (2, 4, 8, 12, 16)
BENCH_BATCH = 100_000
BENCH_REPEAT = 3

#: finite-difference steps of ``--eps``: below 1e-12 rounding swamps the difference
#: quotient, above 0.1 the step leaves the neighbourhood where the B-derivative describes
#: the flow
EPS_RANGE = (1e-12, 0.1)
#: largest n of the scalable network family the CLI accepts (a judgement: its dense table
#: has 2**n rows)
NETWORK_MAX_N = 20
#: random vectors on which every file ``export`` reads back is compared with the
#: B-derivative (a judgement: a wrong entry shows on any random vector)
CHECK_VECTORS = 200
#: corner tables with more entries than this are left out of ``--full`` output (a
#: judgement: longer tables are not read)
FULL_TABLE_ENTRIES = 1 << 14
#: Agg's bound on the pixels of a side of a raster image
MAX_SIDE_PIXELS = 1 << 16
#: the most pixels of a raster image that image libraries open without refusing it as a
#: decompression bomb (Pillow's MAX_IMAGE_PIXELS, about 89 million)
MAX_PIXELS = 89_478_485
