/* Instruction counter for qemu-user (a TCG plugin): counts the guest instructions the emulated program executes
 * and writes "insns <N>" to the file named by the plugin argument outfile=PATH (stderr without it) when the
 * program exits. Debian's qemu-user runs plugins (-plugin) but ships none and no plugin header, so the few entry
 * points used are declared here (the plugin API of QEMU 4.2 to 8.x, version 1).
 *
 *   cc -shared -fPIC -O2 -o libdiekf_insn.so cross/qemu_insn_count.c
 *   qemu-aarch64 -L SYSROOT -plugin ./libdiekf_insn.so,outfile=insns.txt ./program args
 *
 * Each translated block adds its instruction count to one counter every time it runs (an inline add, no
 * callback per instruction); single-threaded programs get an exact count. Used by cross/cross_check.sh for the
 * instructions per frame of the ARM builds (docs/performance.md, "ARM"). */
#include <inttypes.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

typedef uint64_t qemu_plugin_id_t;
struct qemu_plugin_tb;
struct qemu_info_t; /* not used */
enum qemu_plugin_op { QEMU_PLUGIN_INLINE_ADD_U64 = 0 };
typedef void (*qemu_plugin_vcpu_tb_trans_cb_t)(qemu_plugin_id_t id, struct qemu_plugin_tb *tb);
typedef void (*qemu_plugin_udata_cb_t)(qemu_plugin_id_t id, void *userdata);

void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t id, qemu_plugin_vcpu_tb_trans_cb_t cb);
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *tb);
void qemu_plugin_register_vcpu_tb_exec_inline(struct qemu_plugin_tb *tb, enum qemu_plugin_op op, void *ptr,
                                              uint64_t imm);
void qemu_plugin_register_atexit_cb(qemu_plugin_id_t id, qemu_plugin_udata_cb_t cb, void *userdata);

__attribute__((visibility("default"))) int qemu_plugin_version = 1;

static uint64_t insn_count;
static char out_path[4096];

static void on_translate(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
  (void)id;
  qemu_plugin_register_vcpu_tb_exec_inline(tb, QEMU_PLUGIN_INLINE_ADD_U64, &insn_count,
                                           (uint64_t)qemu_plugin_tb_n_insns(tb));
}

static void on_exit_cb(qemu_plugin_id_t id, void *userdata) {
  (void)id;
  (void)userdata;
  FILE *f = out_path[0] != '\0' ? fopen(out_path, "w") : NULL;
  fprintf(f != NULL ? f : stderr, "insns %" PRIu64 "\n", insn_count);
  if (f != NULL) fclose(f);
}

__attribute__((visibility("default"))) int qemu_plugin_install(qemu_plugin_id_t id, const struct qemu_info_t *info,
                                                               int argc, char **argv) {
  (void)info;
  for (int i = 0; i < argc; ++i) {
    if (strncmp(argv[i], "outfile=", 8) == 0) {
      strncpy(out_path, argv[i] + 8, sizeof(out_path) - 1);
    } else {
      fprintf(stderr, "qemu_insn_count: unknown argument '%s' (outfile=PATH)\n", argv[i]);
      return -1;
    }
  }
  qemu_plugin_register_vcpu_tb_trans_cb(id, on_translate);
  qemu_plugin_register_atexit_cb(id, on_exit_cb, NULL);
  return 0;
}
