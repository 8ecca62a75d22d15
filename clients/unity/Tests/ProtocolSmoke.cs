using System;
using System.Collections.Generic;
using System.Globalization;
using System.IO;
using System.Linq;
using System.Net.Http;
using System.Text;
using System.Threading;
using System.Threading.Tasks;

namespace Vista.Client.Smoke
{
    /// <summary>
    /// Runs the protocol core against a live supervisor, the way a headset would: sign in,
    /// list and sync an inspection in pages, fetch and read the scene, align on its markers,
    /// judge offline and push (applied, a retry replayed, a stale one, an answer lost on the
    /// network and replayed after a restart from saved state, batches with a rejected one),
    /// then filter, sort and print the defect list. Prints one JSON line of findings; exit
    /// code 0 only when every check passed.
    /// Usage: mono smoke.exe BASE_URL USERNAME PASSWORD INSPECTION_ID
    /// </summary>
    public static class ProtocolSmoke
    {
        const int PageLimit = 3;
        const double Tolerance = 1e-9;
        const string Comment = "Spalt größer als 1 mm – \"gut sichtbar\"\n\U0001F440";

        /// <summary>Entry point: 0 all checks passed, 1 a check failed, 2 bad arguments.</summary>
        public static int Main(string[] args)
        {
            long inspectionId;
            if (args.Length != 4 || !long.TryParse(args[3], NumberStyles.None, CultureInfo.InvariantCulture, out inspectionId))
            {
                Console.Error.WriteLine("usage: mono smoke.exe BASE_URL USERNAME PASSWORD INSPECTION_ID");
                return 2;
            }
            Console.OutputEncoding = new UTF8Encoding(false);
            // A comma-decimal culture, as on a German headset: the wire format must not notice.
            var german = new CultureInfo("de-DE");
            CultureInfo.DefaultThreadCurrentCulture = german;
            CultureInfo.CurrentCulture = german;
            try
            {
                Dictionary<string, object> summary = RunAsync(args[0], args[1], args[2], inspectionId).GetAwaiter().GetResult();
                Console.WriteLine(Json.Serialize(summary));
                return 0;
            }
            catch (CheckFailed failure)
            {
                Console.Error.WriteLine("protocol smoke test failed: " + failure.Message);
            }
            catch (Exception error)
            {
                Console.Error.WriteLine("protocol smoke test failed with an error: " + error);
            }
            return 1;
        }

        static async Task<Dictionary<string, object>> RunAsync(string baseUrl, string username, string password, long inspectionId)
        {
            var summary = new Dictionary<string, object>();
            CheckJson(summary);
            var network = new LossyHandler(VistaApi.CreateHandler());
            using (var api = new VistaApi(baseUrl, network))
            {
                UserInfo me = await SignIn(api, username, password, summary);
                Inspection inspection = await FindInspection(api, inspectionId, summary);

                var device = new SyncClient(api, inspectionId) { User = me, PageLimit = PageLimit };
                int pages = await device.SyncAsync();
                int count = device.Defects.Count;
                Check(count >= 6, "the inspection needs at least 6 defects, the sync brought " + count);
                Check(pages == (count + PageLimit - 1) / PageLimit, "a full sync of " + count + " defects in pages of " + PageLimit + " took " + pages + " pages");
                Check(device.Inspection != null && device.Inspection.Title == inspection.Title, "the sync's first page carries the inspection");
                Check(await device.SyncAsync() == 1, "a sync with nothing new takes one page");
                summary["defects"] = count;
                summary["sync_pages"] = pages;
                summary["warnings"] = device.Warnings.Select(w => (object)new Dictionary<string, object>
                {
                    { "job_id", w.JobId }, { "warning", w.Warning }, { "unmeasured_seams", w.UnmeasuredSeams },
                }).ToList();
                summary["uncertain_defects"] = device.Defects.Values
                    .Where(d => d.ToleranceState == "uncertain").Select(d => (object)d.Id).OrderBy(id => id).ToList();

                await CheckScene(device, inspection, summary);

                long[] ids = device.Defects.Keys.OrderBy(id => id).Take(6).ToArray();
                await JudgeAndPush(api, device, ids[0], me, summary);
                await PushStale(api, device, ids[1], me, summary);
                SyncClient restarted = await LoseAnswerAndRestart(api, device, network, ids[2], me, summary);
                await PushInBatches(api, restarted, network, ids[3], ids[4], ids[5], me, summary);
                await restarted.SyncAsync();
                CheckList(restarted, summary);
            }
            return summary;
        }

        /// <summary>The JSON reader and writer on the corners: escapes, surrogate pairs, number
        /// forms, round trips, and texts that are not JSON.</summary>
        static void CheckJson(Dictionary<string, object> summary)
        {
            const string text = "{\"s\":\"q\\\"b\\\\s\\/n\\n\\u00e9\\ud83d\\udc40\\u0001\",\"i\":-42,"
                + "\"big\":12345678901234567890,\"r\":1.5e-7,\"e\":2E+3,\"t\":true,\"f\":false,\"n\":null,\"a\":[[],{}]}";
            Dictionary<string, object> parsed = Json.ParseObject(text);
            Check(parsed.GetString("s") == "q\"b\\s/n\n\u00e9\U0001F440\u0001", "JSON: string escapes read wrong");
            Check(parsed["i"] is long && (long)parsed["i"] == -42, "JSON: a negative integer read wrong");
            Check(parsed["big"] is double && (double)parsed["big"] == 12345678901234567890.0, "JSON: an integer past long read wrong");
            Check((double)parsed["r"] == 1.5e-7 && (double)parsed["e"] == 2000.0, "JSON: exponents read wrong");
            Check((bool)parsed["t"] && !(bool)parsed["f"] && parsed["n"] == null && parsed.GetArray("a").Count == 2, "JSON: literals or nesting read wrong");
            string written = Json.Serialize(parsed);
            Check(Json.Serialize(Json.Parse(written)) == written, "JSON: a round trip changed " + written);
            Check(Json.Serialize("\u0001\"\\\n\U0001F440\ud800") == "\"\\u0001\\\"\\\\\\n\U0001F440\\ud800\"", "JSON: strings written wrong");
            Check(Json.Serialize(new object[] { 0.1, 1e21, -2.5e-8, 7L, 3 }) == "[0.1,1E+21,-2.5E-08,7,3]", "JSON: numbers written " + Json.Serialize(new object[] { 0.1, 1e21, -2.5e-8, 7L, 3 }));
            string[] notJson = { "", "[1,]", "{\"a\":1,}", "01", "-", "1.", ".5", "1e", "tru", "NaN", "[1] x", "{'a':1}", "\"\\x\"", "\"\u0001\"", "\"abc", "[1e999]" };
            foreach (string bad in notJson)
            {
                try
                {
                    Json.Parse(bad);
                    throw new CheckFailed("JSON: '" + bad + "' was accepted");
                }
                catch (FormatException)
                {
                    // Refused, as it should be.
                }
            }
            summary["json_cases"] = notJson.Length;
        }

        static async Task<UserInfo> SignIn(VistaApi api, string username, string password, Dictionary<string, object> summary)
        {
            try
            {
                await api.SignInAsync(username, password + "-wrong");
                throw new CheckFailed("a wrong password was accepted");
            }
            catch (VistaApiException problem)
            {
                Check(problem.Status == 401 && !string.IsNullOrEmpty(problem.Detail),
                    "a wrong password gives 401 with a detail, got " + problem.Status + " '" + problem.Detail + "'");
                summary["problem_detail"] = problem.Detail;
            }
            TokenInfo token = await api.SignInAsync(username, password);
            UserInfo me = await api.GetMeAsync();
            Check(me.Username == username, "/me names " + me.Username + ", not " + username);
            summary["signed_in"] = !string.IsNullOrEmpty(token.AccessToken);
            summary["user_id"] = me.Id;
            return me;
        }

        static async Task<Inspection> FindInspection(VistaApi api, long inspectionId, Dictionary<string, object> summary)
        {
            bool listed = false;
            string cursor = null;
            do
            {
                InspectionPage page = await api.ListInspectionsAsync(cursor, 50);
                listed |= page.Items.Any(i => i.Id == inspectionId);
                cursor = page.NextCursor;
            }
            while (cursor != null);
            Check(listed, "inspection " + inspectionId + " is not in the list of inspections");
            Inspection inspection = await api.GetInspectionAsync(inspectionId);
            Check(inspection.Id == inspectionId, "GET /inspections/{id} gave another inspection");
            summary["inspection_listed"] = listed;
            return inspection;
        }

        /// <summary>scene.glb: a node per defect with its data, an anchor per marker where the
        /// base-frame pose puts it, a 304 for the same ETag; alignment recovers a known pose.</summary>
        static async Task CheckScene(SyncClient device, Inspection inspection, Dictionary<string, object> summary)
        {
            SceneDownload first = await device.DownloadSceneAsync(false);
            Check(!first.NotModified && first.Bytes != null && first.Bytes.Length > 0, "scene.glb came empty");
            Check(!device.SceneChanged, "the scene just downloaded counts as changed");
            GlbScene scene = GlbScene.Parse(first.Bytes);
            Check(scene.AssetExtras.GetString("scene_etag") == first.ETag, "the scene's asset.extras.scene_etag is not its ETag");
            foreach (Defect defect in device.Defects.Values)
            {
                Dictionary<string, object> extras;
                Check(scene.DefectExtras.TryGetValue(defect.Id, out extras), "scene.glb has no node defect-" + defect.Id);
                Check(extras.GetString("type") == defect.Type, "node defect-" + defect.Id + " has another type");
            }
            Check(scene.DefectExtras.Count == device.Defects.Count, "scene.glb has defect nodes the sync did not bring");
            SceneDownload again = await device.DownloadSceneAsync(true);
            Check(again.NotModified && again.Bytes == null && again.ETag == first.ETag, "the same ETag in If-None-Match did not give 304");

            double anchorError = 0, alignmentError = 0;
            Matrix4 worldFromSceneTruth = new Pose(1.5, -0.25, 3.0, 0.0, Math.Sin(0.3), 0.0, Math.Cos(0.3)).ToMatrix();
            foreach (ImageMarker marker in inspection.Markers)
            {
                Pose anchor;
                Check(scene.MarkerAnchors.TryGetValue(marker.Name, out anchor), "scene.glb has no node marker-" + marker.Name);
                anchorError = Math.Max(anchorError, anchor.ToMatrix().MaxDifference(Alignment.BaseToScene(marker.BaseFromMarker).ToMatrix()));
                Pose seen = Pose.FromMatrix(worldFromSceneTruth * anchor.ToMatrix());
                alignmentError = Math.Max(alignmentError, Alignment.WorldFromScene(seen, anchor).MaxDifference(worldFromSceneTruth));
            }
            Check(anchorError < 1e-6, "an anchor node is " + anchorError + " off the marker's base-frame pose");
            Check(alignmentError < Tolerance, "alignment recovered the scene's pose " + alignmentError + " off");
            summary["scene_defect_nodes"] = scene.DefectExtras.Count;
            summary["scene_not_modified"] = again.NotModified;
            summary["anchors"] = scene.MarkerAnchors.Count;
            summary["anchor_error"] = anchorError;
            summary["alignment_error"] = alignmentError;
        }

        /// <summary>A judgment shows at once, is applied by the push, is counted by the server's
        /// consensus on the next sync, and a retry of the same item is answered as the first time.</summary>
        static async Task JudgeAndPush(VistaApi api, SyncClient device, long defectId, UserInfo me, Dictionary<string, object> summary)
        {
            OfflineJudgment item = device.Judge(defectId, Verdicts.Confirmed, null, Comment);
            Judgment shown = device.JudgmentOf(defectId, me.Id);
            Check(device.Outbox.Count == 1 && shown != null && shown.Verdict == Verdicts.Confirmed && shown.Revision == 0,
                "a judgment made offline does not show at once");
            Check(device.ConsensusOf(defectId).CountOf(Verdicts.Confirmed) == 1, "the local tally does not count the offline judgment");
            Check(item.ClientTime.EndsWith("Z", StringComparison.Ordinal), "client_time " + item.ClientTime + " is not UTC with a Z");

            List<ItemResult> results = await device.PushAsync();
            Check(results.Count == 1 && results[0].ClientId == item.ClientId && !results[0].Replayed, "the push did not answer the item");
            Check(results[0].Status == ItemResult.Applied, "the push answered " + results[0].Status + ": " + results[0].Detail);
            Check(device.Outbox.Count == 0, "an applied item stayed in the outbox");
            Check(device.JudgmentOf(defectId, me.Id).Revision == 1, "the local judgment is not the server's after the push");

            await device.SyncAsync();
            Consensus consensus = device.ConsensusOf(defectId);
            Check(consensus != null && consensus.Total == 1 && consensus.CountOf(Verdicts.Confirmed) == 1 && consensus.Majority == Verdicts.Confirmed,
                "the server's consensus does not count the judgment");
            Check(!device.SceneChanged, "a judgment changed the scene's ETag: every headset would download the scene again for it");

            PushResult retry = await api.PushJudgmentsAsync(new List<OfflineJudgment> { item });
            Check(retry.Results.Count == 1 && retry.Results[0].Replayed && retry.Results[0].Status == ItemResult.Applied,
                "a retried item was not replayed as applied");
            summary["defect_id"] = defectId;
            summary["verdict"] = item.Verdict;
            summary["comment"] = device.JudgmentOf(defectId, me.Id).Comment;
            summary["pushed"] = results[0].Status;
            summary["replayed"] = retry.Results[0].Replayed;
            summary["consensus_total"] = consensus.Total;
            summary["consensus_confirmed"] = consensus.CountOf(Verdicts.Confirmed);
            summary["scene_changed"] = device.SceneChanged;
        }

        /// <summary>The same user judges one defect on two devices; the later judgment arrives
        /// first, the earlier one is stale and the server's judgment replaces it locally.</summary>
        static async Task PushStale(VistaApi api, SyncClient device, long defectId, UserInfo me, Dictionary<string, object> summary)
        {
            var other = new SyncClient(api, device.InspectionId) { User = me };
            await other.SyncAsync();
            device.Judge(defectId, Verdicts.Uncertain, null, "older");
            other.Judge(defectId, Verdicts.Rejected, null, "newer");
            List<ItemResult> newer = await other.PushAsync();
            Check(newer.Count == 1 && newer[0].Status == ItemResult.Applied, "the newer judgment was not applied");
            List<ItemResult> older = await device.PushAsync();
            Check(older.Count == 1 && older[0].Status == ItemResult.Stale, "the older judgment came back " + older[0].Status + ", not stale");
            Judgment shown = device.JudgmentOf(defectId, me.Id);
            Check(shown.Verdict == Verdicts.Rejected && shown.Comment == "newer", "a stale judgment was not replaced by the server's");
            summary["stale_replaced"] = true;
        }

        /// <summary>The server applies a push but its answer is lost: the item stays in the
        /// outbox, survives a restart from saved state, and the next push is answered replayed.</summary>
        static async Task<SyncClient> LoseAnswerAndRestart(VistaApi api, SyncClient device, LossyHandler network, long defectId, UserInfo me, Dictionary<string, object> summary)
        {
            device.Judge(defectId, Verdicts.Confirmed, null, "");
            network.LoseNextAnswer = true;
            try
            {
                await device.PushAsync();
                throw new CheckFailed("a push whose answer was lost did not fail");
            }
            catch (HttpRequestException)
            {
                Check(device.Outbox.Count == 1, "an unanswered item left the outbox");
            }
            string path = Path.Combine(Path.GetTempPath(), "vista-smoke-" + Guid.NewGuid().ToString("N") + ".json");
            try
            {
                device.SaveState(path);
                device.SaveState(path); // the second save replaces the first file
                var restarted = new SyncClient(api, device.InspectionId);
                Check(restarted.LoadState(path), "the saved state was not found");
                Check(restarted.Outbox.Count == 1 && restarted.Outbox[0].ClientId == device.Outbox[0].ClientId, "the outbox did not survive the restart");
                Check(restarted.Cursor == device.Cursor && restarted.Defects.Count == device.Defects.Count && restarted.User.Id == me.Id,
                    "the cursor, defects or user did not survive the restart");
                Check(restarted.DownloadedSceneEtag == device.DownloadedSceneEtag && restarted.SceneChanged == device.SceneChanged,
                    "the scene's ETags did not survive the restart");
                summary["warnings_restored"] = device.Warnings.Count > 0
                    && Json.Serialize(restarted.Warnings.Select(w => (object)w.ToJson()).ToList())
                        == Json.Serialize(device.Warnings.Select(w => (object)w.ToJson()).ToList());
                Check(restarted.Inspection.Markers.Count == device.Inspection.Markers.Count
                    && restarted.Inspection.Markers.Zip(device.Inspection.Markers, (a, b) => a.BaseFromMarker.MaxDifference(b.BaseFromMarker)).All(d => d == 0),
                    "the markers did not survive the restart");
                foreach (Defect defect in device.Defects.Values)
                {
                    Consensus before = device.ConsensusOf(defect.Id), after = restarted.ConsensusOf(defect.Id);
                    Check(Json.Serialize(restarted.Defects[defect.Id].ToJson()) == Json.Serialize(defect.ToJson())
                        && (before == null) == (after == null) && (before == null || Json.Serialize(before.ToJson()) == Json.Serialize(after.ToJson())),
                        "defect " + defect.Id + " or its consensus changed across the restart");
                }
                Check(!restarted.LoadState(path + ".missing"), "a missing state file was loaded");

                List<ItemResult> results = await restarted.PushAsync();
                Check(results.Count == 1 && results[0].Replayed && results[0].Status == ItemResult.Applied,
                    "the item whose answer was lost was not replayed as applied");
                Check(restarted.Outbox.Count == 0, "the replayed item stayed in the outbox");
                summary["state_restored"] = true;
                summary["lost_answer_replayed"] = results[0].Replayed;
                return restarted;
            }
            finally
            {
                File.Delete(path);
            }
        }

        /// <summary>Reclassifying a defect as its own type is refused before it is queued. Three
        /// judgments pushed two per request: the one made on a clock hours ahead is rejected,
        /// its optimistic local judgment goes away and it is kept in Refused with the server's
        /// reason (across a restart) until cleared; the others apply.</summary>
        static async Task PushInBatches(VistaApi api, SyncClient device, LossyHandler network, long refusedId, long uncertainId, long confirmedId, UserInfo me, Dictionary<string, object> summary)
        {
            try
            {
                device.Judge(refusedId, Verdicts.Reclassified, device.Defects[refusedId].Type, "");
                throw new CheckFailed("reclassifying a defect as its own type was queued");
            }
            catch (ArgumentException local)
            {
                Check(local.Message.Contains("already is a " + device.Defects[refusedId].Type) && device.Outbox.Count == 0,
                    "the same-type reclassification was refused as '" + local.Message + "'");
            }
            device.Judge(uncertainId, Verdicts.Uncertain, null, "cannot see it from here");
            device.Judge(confirmedId, Verdicts.Confirmed, null, "");
            device.Clock = () => DateTime.UtcNow.AddHours(2);
            device.Judge(refusedId, Verdicts.Confirmed, null, "clock ahead");
            Check(device.JudgmentOf(refusedId, me.Id) != null, "the judgment does not show at once");
            device.BatchSize = 2;
            int requestsBefore = network.Requests;
            List<ItemResult> results = await device.PushAsync();
            Check(network.Requests - requestsBefore == 2, "3 items in batches of 2 took " + (network.Requests - requestsBefore) + " requests");
            Check(results.Select(r => r.Status).SequenceEqual(new[] { ItemResult.Applied, ItemResult.Applied, ItemResult.Rejected }),
                "the batches answered " + string.Join(", ", results.Select(r => r.Status)));
            Check(!string.IsNullOrEmpty(results[2].Detail), "the rejection has no detail");
            Check(device.JudgmentOf(refusedId, me.Id) == null && device.ConsensusOf(refusedId) == null && device.Outbox.Count == 0,
                "a rejected judgment stayed in the local copy");
            Check(device.Refused.Count == 1 && device.Refused[0].Item.DefectId == refusedId && device.Refused[0].Reason == results[2].Detail,
                "the rejected judgment is not kept in Refused with the server's reason");
            Check(device.ConsensusOf(uncertainId).NeedsReview, "a defect judged uncertain does not need review");
            string path = Path.Combine(Path.GetTempPath(), "vista-smoke-" + Guid.NewGuid().ToString("N") + ".json");
            try
            {
                device.SaveState(path);
                var restarted = new SyncClient(api, device.InspectionId);
                restarted.LoadState(path);
                Check(restarted.Refused.Count == 1 && restarted.Refused[0].Item.Comment == "clock ahead" && restarted.Refused[0].Reason == results[2].Detail,
                    "the refused judgment did not survive a restart");
            }
            finally
            {
                File.Delete(path);
            }
            Check(device.ClearRefused() == 1 && device.Refused.Count == 0, "ClearRefused did not clear");
            summary["push_requests"] = network.Requests - requestsBefore;
            summary["rejected_detail"] = results[2].Detail;
            summary["refused_kept"] = true;
        }

        /// <summary>The defect window's model: filters, sort orders, stepping through the
        /// selection, and the line of text of each defect.</summary>
        static void CheckList(SyncClient device, Dictionary<string, object> summary)
        {
            var list = new DefectListModel(device);
            List<Defect> all = list.Rows();
            Check(all.Select(d => d.Id).SequenceEqual(device.Defects.Keys.OrderBy(id => id)), "the unfiltered list is not every defect by id");
            string type = all[0].Type;
            list.TypeFilter = type;
            Check(list.Rows().Count == all.Count(d => d.Type == type) && list.Rows().All(d => d.Type == type), "the type filter lets other types through");
            list.TypeFilter = null;
            list.StatusFilter = "no such status";
            Check(list.Rows().Count == 0 && list.Step(1) == null, "a filter that matches nothing still shows rows");
            list.StatusFilter = null;
            list.SortBy = DefectSortKey.Value;
            list.Descending = true;
            List<double> values = list.Rows().Where(d => d.Value.HasValue && d.Unit == "mm").Select(d => d.Value.Value).ToList();
            Check(values.Zip(values.Skip(1), (a, b) => a >= b).All(ok => ok), "sorting by value, descending, is out of order");
            list.Descending = false;
            list.SortBy = DefectSortKey.Agreement;
            Check(device.ConsensusOf(list.Rows()[0].Id) == null, "sorting by agreement does not put unjudged defects first");
            list.SortBy = DefectSortKey.Id;
            Check(list.Step(1) == all[0].Id && list.Step(-1) == all[all.Count - 1].Id && list.Selected.Id == all[all.Count - 1].Id,
                "stepping through the list does not wrap around");
            summary["list_lines"] = all.Select(list.Line).ToList();
        }

        static void Check(bool condition, string failure)
        {
            if (!condition)
            {
                throw new CheckFailed(failure);
            }
        }

        sealed class CheckFailed : Exception
        {
            public CheckFailed(string message)
                : base(message)
            {
            }
        }

        /// <summary>Passes requests on; when told, lets the server answer but drops the answer,
        /// as a network that fails at the worst moment would.</summary>
        sealed class LossyHandler : DelegatingHandler
        {
            public LossyHandler(HttpMessageHandler inner)
                : base(inner)
            {
            }

            public bool LoseNextAnswer { get; set; }

            public int Requests { get; private set; }

            protected override async Task<HttpResponseMessage> SendAsync(HttpRequestMessage request, CancellationToken cancellationToken)
            {
                Requests++;
                HttpResponseMessage response = await base.SendAsync(request, cancellationToken).ConfigureAwait(false);
                if (LoseNextAnswer)
                {
                    LoseNextAnswer = false;
                    response.Dispose();
                    throw new HttpRequestException("simulated: the connection dropped before the answer arrived");
                }
                return response;
            }
        }
    }
}
