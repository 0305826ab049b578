/* Every limit needlesim puts on untrusted input, in one place, with its unit and its reason
 * (STYLE.md: the SQLite model: a named limit, checked before the work or the allocation it
 * bounds). Scenarios, meshes, trainee logs and live messages come from other people; each of
 * these is checked where the value is used, whatever a constructor checked earlier.
 * docs/reliability.md lists them for users. */
#ifndef NS_NS_LIMITS_H
#define NS_NS_LIMITS_H

/* ---- controls (scripts, trainee logs and live messages alike) -------------------------------
 * Physical bounds, well above any clinical or robotic procedure, so that the work a step does
 * (the reparameterization's splits, the remesher's pieces) is bounded by construction. */

/* Insertion or retraction speed |v_insert| [m/s]. Hand insertion runs 1-10 mm/s, robotic
 * insertion up to ~0.1 m/s; the stability map (docs/stability.csv) goes to 0.2 m/s. */
#define NS_LIMIT_INSERT_SPEED 0.5
/* Base twist rate |twist_rate| [rad/s]: 10 turns a second (duty-cycled spinning, Engh et al.
 * 2006 and Majewicz et al. 2014, spins at 1-10 turns a second). */
#define NS_LIMIT_TWIST_RATE 63.0
/* Sleeve (base) velocity, each component [m/s]: as the insertion speed. */
#define NS_LIMIT_BASE_SPEED 0.5
/* One twist angle (act.twist{angle}, a live {"twist": rad}) [rad]: 100 turns. */
#define NS_LIMIT_TWIST_ANGLE 628.0
/* The force steering model's k_b (needle.bevel_force) [N]: the lateral tip force at
 * tan(psi) = 1. The default is 0.5 N; 10 N pushes any needle's tip sideways harder than the
 * axial forces of a whole insertion (a few newtons, materials.lua). */
#define NS_LIMIT_BEVEL_FORCE 10.0

/* Nodes of the needle's rod after a reparameterization (§3.4.2): a rod of 0.3 m at the finest
 * edge any scenario uses (0.1 mm) has 3,000. */
#define NS_LIMIT_ROD_NODES 10000

/* ---- time --------------------------------------------------------------------------------- */

/* The time step dt [s]: above this the coupled step's Newmark update is far outside what any
 * validation case covers; below the minimum a run of a second is millions of steps. */
#define NS_LIMIT_DT_MAX 0.1
#define NS_LIMIT_DT_MIN 1e-6
/* Simulated time a run may last when its scenario gives no duration [s]: a script that never
 * ends (act.wait in a loop) stops here and the report says it had not finished. */
#define NS_LIMIT_DEFAULT_SIM_TIME 120.0
/* The longest duration a scenario may ask for [s] (one hour of procedure). */
#define NS_LIMIT_SIM_TIME_MAX 3600.0
/* Steps in one run, whatever dt and duration say. */
#define NS_LIMIT_STEPS 2000000L

/* ---- scenario scripts --------------------------------------------------------------------- */

/* Lua VM instructions for loading a scenario (the file, its modules, its shape functions as
 * the mesher calls them), all together. */
#define NS_LIMIT_LOAD_INSTRUCTIONS 500000000LL
/* Lua VM instructions for the whole of a run's script and on_tick calls, all together. */
#define NS_LIMIT_RUN_INSTRUCTIONS 5000000000LL
/* Wall-clock time one tick of a run's script and on_tick may take [s]. */
#define NS_LIMIT_TICK_SECONDS 10.0
/* Memory one scenario's Lua state may hold [bytes]. */
#define NS_LIMIT_LUA_MEMORY ((size_t)256 << 20)
/* Wall-clock time loading a scenario may take, meshing included [s]. */
#define NS_LIMIT_LOAD_SECONDS 60.0
/* The string library's pattern functions (find, match, gmatch, gsub): longest subject and
 * pattern [bytes]; the worst-case work of a call is estimated before it runs and charged to the
 * budget (backtracking is C code the instruction hook never sees). */
#define NS_LIMIT_PATTERN_SUBJECT 65536
#define NS_LIMIT_PATTERN_LENGTH  256
/* Matching steps a pattern call may need in the worst case (about a second of C). */
#define NS_LIMIT_PATTERN_WORK 1e8

/* ---- files -------------------------------------------------------------------------------- */

/* A mesh file (Gmsh .msh, VTK .vtu/.vtk) [bytes]: ~10 million tets in ASCII. */
#define NS_LIMIT_MESH_FILE_BYTES ((long long)1 << 30)
/* A trainee log [bytes]: an hour at 10 kHz. */
#define NS_LIMIT_LOG_FILE_BYTES ((long long)256 << 20)
/* A scenario file or module [bytes]. */
#define NS_LIMIT_SCRIPT_FILE_BYTES ((long long)16 << 20)
/* A scenario's dosimetry (engine/run_spec.c; scripts/needlesim.lua checks the same): planned
 * seeds, prescription [Gy], a seed's air-kerma strength [U], the dose grid's spacing [m]. */
#define NS_LIMIT_DOSE_PLAN_SEEDS   1000
#define NS_LIMIT_DOSE_PRESCRIPTION 1000.0
#define NS_LIMIT_DOSE_STRENGTH     10.0
#define NS_LIMIT_DOSE_SPACING_MIN  0.5e-3
#define NS_LIMIT_DOSE_SPACING_MAX  5e-3
/* A dosimetry table (the assets/tg43 CSV files) [bytes]: the 6711 table is ~4 kB. */
#define NS_LIMIT_DOSE_TABLE_BYTES ((long long)1 << 20)
/* An authored video's cues (engine/run_video.c; scripts/needlesim/actions.lua checks the
 * same): cues in a run, bytes of a caption's, chapter's or card's text, a caption's or camera
 * move's duration [s], a card's [s], the slow-motion factor, the camera's zoom, its orbit [deg]. */
#define NS_LIMIT_VIDEO_CUES     1000
#define NS_LIMIT_VIDEO_TEXT     200
#define NS_LIMIT_VIDEO_DURATION 600.0
#define NS_LIMIT_VIDEO_CARD_S   10.0
#define NS_LIMIT_VIDEO_SLOW     16.0
#define NS_LIMIT_VIDEO_ZOOM     20.0
#define NS_LIMIT_VIDEO_ORBIT    720.0

/* ---- meshes ------------------------------------------------------------------------------- */

/* Memory the mesher may plan to use [bytes], estimated from the lattice before it allocates;
 * past it the message states the coarsest resolution that would fit. */
#define NS_LIMIT_MESHER_BYTES ((long long)2 << 30)

/* Shape nodes (primitives, CSG operations, functions) in one tissue: the mesher evaluates
 * every node at every lattice vertex. */
#define NS_LIMIT_SHAPE_NODES 10000

/* ---- live sessions (docs/live.md) ------------------------------------------------------------ */

/* One client message [bytes]: the largest control message is under 100 bytes. */
#define NS_LIMIT_LIVE_MESSAGE_BYTES 4096
/* WebSocket clients (one controls, the others watch) and MJPEG viewers at once: each holds a
 * server thread and a sender thread. */
#define NS_LIMIT_LIVE_CLIENTS 8
#define NS_LIMIT_LIVE_VIEWERS 8
/* Frames a second a session may be asked for, and its frame size [pixels] (as --width). */
#define NS_LIMIT_LIVE_FPS 120

/* ---- names -------------------------------------------------------------------------------- */

/* Names that end up in CSV headers and JSON (targets, markers, obstacles, regions) [bytes]. */
#define NS_LIMIT_NAME_LENGTH 64
/* A scenario's name (free text: reports, logs' provenance) [bytes]. */
#define NS_LIMIT_SCENARIO_NAME 200

#endif
