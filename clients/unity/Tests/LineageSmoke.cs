using System;
using System.Collections.Generic;
using System.Globalization;
using System.IO;
using System.Linq;
using System.Text;
using System.Threading.Tasks;

namespace Vista.Client.Smoke
{
    /// <summary>
    /// A verdict queued offline while the part is measured again, read by the protocol core
    /// against a live supervisor: sync, judge DEFECT_ID offline (queued, not sent), print
    /// "queued" and wait for a line on standard input (the part measured again meanwhile);
    /// then sync (the finding leaves the list, its successor shows the queued verdict), push
    /// (the verdict lands on the successor), sync again. Prints one JSON line of what it saw.
    /// Usage: mono lineage.exe BASE_URL USERNAME PASSWORD INSPECTION_ID DEFECT_ID
    /// </summary>
    public static class LineageSmoke
    {
        /// <summary>Entry point: 0 done, 1 a failure, 2 bad arguments.</summary>
        public static int Main(string[] args)
        {
            long inspectionId, defectId;
            if (args.Length != 5
                || !long.TryParse(args[3], NumberStyles.None, CultureInfo.InvariantCulture, out inspectionId)
                || !long.TryParse(args[4], NumberStyles.None, CultureInfo.InvariantCulture, out defectId))
            {
                Console.Error.WriteLine("usage: mono lineage.exe BASE_URL USERNAME PASSWORD INSPECTION_ID DEFECT_ID");
                return 2;
            }
            Console.OutputEncoding = new UTF8Encoding(false);
            try
            {
                Console.WriteLine(Json.Serialize(RunAsync(args[0], args[1], args[2], inspectionId, defectId).GetAwaiter().GetResult()));
                return 0;
            }
            catch (Exception error)
            {
                Console.Error.WriteLine("lineage smoke test failed: " + error);
                return 1;
            }
        }

        static async Task<Dictionary<string, object>> RunAsync(string baseUrl, string username, string password, long inspectionId, long defectId)
        {
            var summary = new Dictionary<string, object>();
            using (var api = new VistaApi(baseUrl, VistaApi.CreateHandler()))
            {
                await api.SignInAsync(username, password);
                var device = new SyncClient(api, inspectionId) { User = await api.GetMeAsync() };
                await device.SyncAsync();
                summary["before"] = device.Defects.Count;
                device.Judge(defectId, Verdicts.Rejected, null, "paint run");
                Console.WriteLine("queued");
                Console.Out.Flush();
                Console.In.ReadLine(); // the part is measured again meanwhile

                await device.SyncAsync();
                long? successor = device.SuccessorOf(defectId);
                summary["after"] = device.Defects.Count;
                summary["ended"] = device.Ended.Count;
                summary["judged_still_listed"] = device.Defects.ContainsKey(defectId);
                summary["successor"] = successor;
                Judgment shown = successor == null ? null : device.JudgmentOf(successor.Value, device.User.Id);
                summary["shown_on_successor"] = shown == null ? null : shown.Verdict;

                List<ItemResult> pushed = await device.PushAsync();
                summary["pushed"] = pushed.Select(r => (object)new Dictionary<string, object>
                {
                    { "defect_id", r.DefectId }, { "status", r.Status }, { "landed_on", r.LandedOn }, { "detail", r.Detail },
                }).ToList();
                await device.SyncAsync();
                Judgment stored = successor == null ? null : device.JudgmentOf(successor.Value, device.User.Id);
                summary["stored_verdict"] = stored == null ? null : stored.Verdict;
                summary["stored_revision"] = stored == null ? 0 : stored.Revision;
                summary["judged_on_run"] = stored == null ? null : stored.JudgedOnRunId;
                string path = Path.Combine(Path.GetTempPath(), "vista-lineage-" + Guid.NewGuid().ToString("N") + ".json");
                device.SaveState(path);
                var restarted = new SyncClient(api, inspectionId);
                restarted.LoadState(path);
                File.Delete(path);
                summary["restored_ended"] = restarted.Ended.Count;
                summary["restored_current"] = restarted.Defects.Count;
            }
            return summary;
        }
    }
}
